/* rig_stats.h -- pose errors and their statistics, exactly as
 * docs/conventions.md defines them (the paper's metrics). */
#ifndef RIG_STATS_H
#define RIG_STATS_H

/* Wrap an angle difference to (-180, 180] degrees. */
double rig_wrap_deg(double a);

/* Per-axis errors e_a = |wrap(pred_a - true_a)|. */
void rig_pose_errors(const double pred[3], const double truth[3], double e[3]);

/* Geodesic error: the angle of R_pred^T R_true, degrees, in [0, 180]. */
double rig_geodesic_deg(const double pred[3], const double truth[3]);

typedef struct {
    double err, std, rmse, max; /* Err_a, Std_a (population), RMSE_a, Max_a */
    double q1, median, q3;      /* quartiles (linear interpolation), for the box plot */
    double whisk_lo, whisk_hi;  /* box-plot whiskers: extreme values within 1.5 IQR */
} rig_axis_stats;

typedef struct {
    int n;                  /* samples */
    rig_axis_stats axis[3]; /* X, Y, Z */
    rig_axis_stats geo;     /* geodesic error */
    double mae, rmse;       /* over all samples and axes */
} rig_summary;

/* Statistics of n samples: e is n x 3 (row-major), geo has n entries (may be
 * NULL). n == 0 gives zeros. Returns 0, or -1 when out of memory. */
int rig_summarise(const double *e, const double *geo, int n, rig_summary *s);

/* Percentile p (0..100) of sorted v[0..n-1], linear interpolation. */
double rig_percentile(const double *sorted, int n, double p);

#endif
