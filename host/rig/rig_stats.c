/* rig_stats.c -- see rig_stats.h. */
#include "rig_stats.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sp_euler.h"

#define DEG (3.14159265358979323846 / 180.0)

double rig_wrap_deg(double a)
{
    double w = fmod(a, 360.0); /* (-360, 360) */
    if (w > 180.0)
        w -= 360.0;
    else if (w <= -180.0)
        w += 360.0;
    return w;
}

void rig_pose_errors(const double pred[3], const double truth[3], double e[3])
{
    int i;
    for (i = 0; i < 3; i++) e[i] = fabs(rig_wrap_deg(pred[i] - truth[i]));
}

double rig_geodesic_deg(const double pred[3], const double truth[3])
{
    double P[3][3], T[3][3], tr = 0, c;
    int i, k;
    sp_euler_to_matrix(pred, P);
    sp_euler_to_matrix(truth, T);
    /* trace(P^T T) = sum over i,k of P[k][i] * T[k][i] */
    for (i = 0; i < 3; i++)
        for (k = 0; k < 3; k++) tr += P[k][i] * T[k][i];
    c = (tr - 1.0) / 2.0;
    if (c > 1.0) c = 1.0;
    if (c < -1.0) c = -1.0;
    return acos(c) / DEG;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double rig_percentile(const double *v, int n, double p)
{
    double pos, frac;
    int lo;
    if (n <= 0) return 0.0;
    pos = p / 100.0 * (n - 1);
    lo = (int)floor(pos);
    if (lo >= n - 1) return v[n - 1];
    if (lo < 0) return v[0];
    frac = pos - lo;
    return v[lo] + frac * (v[lo + 1] - v[lo]);
}

/* Statistics of one column (stride apart in data). */
static int column_stats(const double *data, int stride, int n, rig_axis_stats *a, double *tmp)
{
    double sum = 0, sq = 0, iqr, lo, hi;
    int i;
    memset(a, 0, sizeof(*a));
    if (n == 0) return 0;
    for (i = 0; i < n; i++) {
        double e = data[(size_t)i * stride];
        tmp[i] = e;
        sum += e;
        sq += e * e;
        if (e > a->max) a->max = e;
    }
    a->err = sum / n;
    a->rmse = sqrt(sq / n);
    /* Population standard deviation, from the deviations (not sq - mean^2,
     * which cancels badly for tightly clustered errors). */
    {
        double d = 0;
        for (i = 0; i < n; i++) d += (tmp[i] - a->err) * (tmp[i] - a->err);
        a->std = sqrt(d / n);
    }
    qsort(tmp, (size_t)n, sizeof(double), cmp_double);
    a->q1 = rig_percentile(tmp, n, 25);
    a->median = rig_percentile(tmp, n, 50);
    a->q3 = rig_percentile(tmp, n, 75);
    iqr = a->q3 - a->q1;
    lo = a->q1 - 1.5 * iqr;
    hi = a->q3 + 1.5 * iqr;
    a->whisk_lo = a->q1;
    a->whisk_hi = a->q3;
    for (i = 0; i < n; i++) {
        if (tmp[i] >= lo && tmp[i] < a->whisk_lo) a->whisk_lo = tmp[i];
        if (tmp[i] <= hi && tmp[i] > a->whisk_hi) a->whisk_hi = tmp[i];
    }
    return 0;
}

int rig_summarise(const double *e, const double *geo, int n, rig_summary *s)
{
    double *tmp, sum = 0, sq = 0;
    int i, k;
    memset(s, 0, sizeof(*s));
    s->n = n;
    if (n <= 0) return 0;
    tmp = malloc((size_t)n * sizeof(double));
    if (!tmp) return -1;
    for (k = 0; k < 3; k++) column_stats(e + k, 3, n, &s->axis[k], tmp);
    if (geo) column_stats(geo, 1, n, &s->geo, tmp);
    for (i = 0; i < n * 3; i++) {
        sum += e[i];
        sq += e[i] * e[i];
    }
    s->mae = sum / (3.0 * n);
    s->rmse = sqrt(sq / (3.0 * n));
    free(tmp);
    return 0;
}
