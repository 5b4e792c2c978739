/* Unit test: docs/poseinfer.md's table of config keys ("Config file") is the
 * program's (host/poseinfer/config.c): the same keys, each documented default
 * what config_init sets, each documented range what config_set accepts. */
#define _POSIX_C_SOURCE 200809L
#include <limits.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "config.h"
#include "poseinfer.h"

#define MAX_ROWS 64

typedef struct row {
    char key[64], def[64], values[160];
    int line;
} row;

/* docs/poseinfer.md, found from this source file's path as the compiler saw
 * it (host/Makefile compiles ../tests/host/unit/test_config_doc.c and runs
 * the test in host/). */
static void doc_path(char *out, size_t len)
{
    const char *here = __FILE__, *cut = strstr(here, "tests/host/unit/");
    assert_non_null(cut);
    snprintf(out, len, "%.*sdocs/poseinfer.md", (int)(cut - here), here);
}

/* Cell k (0-based) of a "| a | b | c |" line, trimmed, into out. */
static int cell(const char *line, int k, char *out, size_t len)
{
    const char *p = strchr(line, '|'), *e;
    for (int i = 0; p && i < k; i++) p = strchr(p + 1, '|');
    if (!p || !(e = strchr(p + 1, '|'))) return -1;
    p++;
    while (p < e && *p == ' ') p++;
    while (e > p && e[-1] == ' ') e--;
    if ((size_t)(e - p) >= len) return -1;
    memcpy(out, p, (size_t)(e - p));
    out[e - p] = '\0';
    return 0;
}

/* `text` -> text (in place); anything else is left as it is. */
static void unquote(char *s)
{
    size_t n = strlen(s);
    if (n >= 2 && s[0] == '`' && s[n - 1] == '`') {
        memmove(s, s + 1, n - 2);
        s[n - 2] = '\0';
    }
}

/* The rows of the table under "## Config file". */
static int read_table(const char *path, row *rows)
{
    FILE *f = fopen(path, "r");
    char line[512];
    int in = 0, n = 0, lineno = 0;
    if (!f) fail_msg("%s: cannot open", path);
    while (fgets(line, sizeof line, f)) {
        lineno++;
        if (!strncmp(line, "## ", 3)) in = !strncmp(line, "## Config file", 14);
        if (!in || strncmp(line, "| `", 3)) continue;
        assert_true(n < MAX_ROWS);
        if (cell(line, 0, rows[n].key, sizeof rows[n].key) < 0 ||
            cell(line, 1, rows[n].def, sizeof rows[n].def) < 0 ||
            cell(line, 2, rows[n].values, sizeof rows[n].values) < 0)
            fail_msg("%s:%d: expected | `key` | default | values |", path, lineno);
        unquote(rows[n].key);
        unquote(rows[n].def);
        rows[n].line = lineno;
        n++;
    }
    fclose(f);
    if (n == 0) fail_msg("%s: no table of keys under \"## Config file\"", path);
    return n;
}

/* config_set on a fresh config: its result (0 or -1). */
static int try_set(const char *key, const char *value)
{
    pi_config c;
    char err[PI_ERR_LEN];
    int rc;
    config_init(&c);
    rc = config_set(&c, key, value, err);
    config_free(&c);
    return rc;
}

static void check_range(const char *path, const row *r)
{
    long lo, hi;
    char v[32];
    int at = 0;
    if (sscanf(r->values, "%ld to %ld%n", &lo, &hi, &at) == 2 && at > 0) {
        const long probe[4][2] = {{lo, 0}, {hi, 0}, {lo - 1, -1}, {hi + 1, -1}};
        for (int i = 0; i < 4; i++) {
            snprintf(v, sizeof v, "%ld", probe[i][0]);
            if (try_set(r->key, v) != probe[i][1])
                fail_msg("%s:%d: %s = %s: the program %s it", path, r->line, r->key, v,
                         probe[i][1] ? "accepts" : "refuses");
        }
    } else if (sscanf(r->values, "%ld (%*[^)]) or more%n", &lo, &at) == 1 && at > 0) {
        snprintf(v, sizeof v, "%ld", lo - 1);
        assert_int_equal(try_set(r->key, v), -1);
        snprintf(v, sizeof v, "%ld", lo);
        assert_int_equal(try_set(r->key, v), 0);
        snprintf(v, sizeof v, "%ld", LONG_MAX);
        assert_int_equal(try_set(r->key, v), 0);
    } else if (!strncmp(r->values, "yes/no", 6)) {
        assert_int_equal(try_set(r->key, "yes"), 0);
        assert_int_equal(try_set(r->key, "no"), 0);
        assert_int_equal(try_set(r->key, "maybe"), -1);
    } else if (!strncmp(r->values, "octal, up to 0777", 17)) {
        assert_int_equal(try_set(r->key, "0777"), 0);
        assert_int_equal(try_set(r->key, "1000"), -1);
        assert_int_equal(try_set(r->key, "0669"), -1);
    }
}

static void table_is_the_programs(void **state)
{
    row rows[MAX_ROWS];
    char path[512];
    int n, i, k;
    (void)state;
    doc_path(path, sizeof path);
    n = read_table(path, rows);

    /* The same keys: each program key once in the table, each row a key. */
    for (k = 0; config_key(k); k++) {
        int found = 0;
        for (i = 0; i < n; i++) found += !strcmp(rows[i].key, config_key(k));
        if (found != 1)
            fail_msg("%s: key %s is in the table %d times (want 1)", path, config_key(k), found);
    }
    assert_int_equal(n, k);

    for (i = 0; i < n; i++) {
        const row *r = &rows[i];
        pi_config c0, c1;
        char err[PI_ERR_LEN];
        config_init(&c0);
        config_init(&c1);
        if (strcmp(r->def, "none")) {
            /* Setting the documented default changes nothing. */
            if (config_set(&c1, r->key, r->def, err) < 0)
                fail_msg("%s:%d: default of %s: %s", path, r->line, r->key, err);
            if (memcmp(&c0, &c1, sizeof c0))
                fail_msg("%s:%d: %s: the program's default is not %s", path, r->line, r->key,
                         r->def);
        } else {
            /* "none": the bytes the key sets are zero (NULL, an empty list) by default. */
            const unsigned char *a = (const unsigned char *)&c0, *b = (const unsigned char *)&c1;
            if (config_set(&c1, r->key, "/x", err) < 0)
                fail_msg("%s:%d: %s: %s", path, r->line, r->key, err);
            for (size_t j = 0; j < sizeof c0; j++)
                if (a[j] != b[j] && a[j] != 0)
                    fail_msg("%s:%d: %s: the program has a default, the table says none", path,
                             r->line, r->key);
        }
        config_free(&c1);
        config_free(&c0);
        check_range(path, r);
    }
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(table_is_the_programs),
    };
    return cmocka_run_group_tests_name("config_doc", tests, NULL, NULL);
}
