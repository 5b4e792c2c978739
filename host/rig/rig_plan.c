/* rig_plan.c -- see rig_plan.h. */
#include "rig_plan.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Three comma-separated finite numbers, spaces allowed around them. */
static int parse_xyz(const char *s, double v[3])
{
    const char *p = s;
    char *end;
    int i;
    for (i = 0; i < 3; i++) {
        while (*p == ' ' || *p == '\t') p++;
        errno = 0;
        v[i] = strtod(p, &end);
        if (end == p || errno || !isfinite(v[i])) return -1;
        p = end;
        while (*p == ' ' || *p == '\t') p++;
        if (i < 2) {
            if (*p != ',') return -1;
            p++;
        }
    }
    return *p == '\0' ? 0 : -1;
}

int rig_plan_load(const char *path, rig_pose **poses, int *n, char *err)
{
    FILE *f = NULL;
    char line[512];
    rig_pose *v = NULL;
    int cap = 0, cnt = 0, lineno = 0, seen_data_or_header = 0;

    *poses = NULL;
    *n = 0;
    if (!(f = fopen(path, "r"))) {
        rig_seterr(err, "fopen(%s): %s", path, strerror(errno));
        return -1;
    }
    while (fgets(line, sizeof(line), f)) {
        size_t len = strlen(line);
        double xyz[3];
        lineno++;
        if (len == sizeof(line) - 1 && line[len - 1] != '\n') {
            rig_seterr(err, "%s:%d: line too long", path, lineno);
            goto fail;
        }
        while (len && (line[len - 1] == '\n' || line[len - 1] == '\r' ||
                       isspace((unsigned char)line[len - 1])))
            line[--len] = '\0';
        if (len == 0 || line[0] == '#') continue;
        if (parse_xyz(line, xyz) != 0) {
            /* Only the first non-blank line may be a header. */
            if (!seen_data_or_header && !isdigit((unsigned char)line[0]) && line[0] != '-' &&
                line[0] != '+' && line[0] != '.') {
                seen_data_or_header = 1;
                continue;
            }
            rig_seterr(err, "%s:%d: expected 'x,y,z' in degrees, got '%.60s'", path, lineno, line);
            goto fail;
        }
        seen_data_or_header = 1;
        if (cnt == RIG_PLAN_MAX) {
            rig_seterr(err, "%s:%d: more than %d poses", path, lineno, RIG_PLAN_MAX);
            goto fail;
        }
        if (cnt == cap) {
            rig_pose *nv;
            cap = cap ? cap * 2 : 64;
            if (!(nv = realloc(v, (size_t)cap * sizeof(*v)))) {
                rig_seterr(err, "%s: out of memory", path);
                goto fail;
            }
            v = nv;
        }
        memcpy(v[cnt].xyz, xyz, sizeof(xyz));
        cnt++;
    }
    if (ferror(f)) {
        rig_seterr(err, "read(%s): %s", path, strerror(errno));
        goto fail;
    }
    if (cnt == 0) {
        rig_seterr(err, "%s: no poses in the plan", path);
        goto fail;
    }
    fclose(f);
    *poses = v;
    *n = cnt;
    return 0;
fail:
    free(v);
    fclose(f);
    return -1;
}

/* splitmix64: tiny, well mixed, and the same on every platform. */
static unsigned long long next_u64(unsigned long long *s)
{
    unsigned long long z = (*s += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

int rig_plan_random(int n, const double range[3][2], unsigned long long seed, rig_pose **poses,
                    char *err)
{
    rig_pose *v;
    unsigned long long st = seed;
    int i, a;
    *poses = NULL;
    if (n < 1 || n > RIG_PLAN_MAX) {
        rig_seterr(err, "rig_plan_random: %d poses, need 1..%d", n, RIG_PLAN_MAX);
        return -1;
    }
    for (a = 0; a < 3; a++) {
        if (!(range[a][0] <= range[a][1]) || !isfinite(range[a][0]) || !isfinite(range[a][1])) {
            rig_seterr(err, "rig_plan_random: bad range for %c", 'x' + a);
            return -1;
        }
    }
    if (!(v = malloc((size_t)n * sizeof(*v)))) {
        rig_seterr(err, "rig_plan_random: out of memory");
        return -1;
    }
    for (i = 0; i < n; i++) {
        for (a = 0; a < 3; a++) {
            double u = (double)(next_u64(&st) >> 11) / 9007199254740992.0; /* [0, 1) */
            double x = range[a][0] + u * (range[a][1] - range[a][0]);
            x = round(x * 1000.0) / 1000.0;
            if (x < range[a][0]) x = range[a][0];
            if (x > range[a][1]) x = range[a][1];
            v[i].xyz[a] = x == 0.0 ? 0.0 : x; /* no -0 */
        }
    }
    *poses = v;
    return 0;
}

int rig_parse_range(const char *s, double *lo, double *hi)
{
    char *end;
    errno = 0;
    *lo = strtod(s, &end);
    if (end == s || *end != ',' || errno || !isfinite(*lo)) return -1;
    s = end + 1;
    *hi = strtod(s, &end);
    if (end == s || *end != '\0' || errno || !isfinite(*hi)) return -1;
    return *lo <= *hi ? 0 : -1;
}
