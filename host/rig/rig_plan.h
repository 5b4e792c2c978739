/* rig_plan.h -- the poses of a rig experiment: from a CSV file or drawn at
 * random in per-axis ranges (degrees). */
#ifndef RIG_PLAN_H
#define RIG_PLAN_H

#include "rig_err.h"

#define RIG_PLAN_MAX 100000

typedef struct {
    double xyz[3];
} rig_pose;

/* Load "x,y,z" lines (degrees). A first line that is not numbers is a header;
 * blank lines and lines starting with '#' are skipped. Anything else that is
 * not exactly three finite numbers is an error naming the file and line.
 * *poses is malloc'd (free it). Returns 0 or -1 with err. */
int rig_plan_load(const char *path, rig_pose **poses, int *n, char *err);

/* n poses uniform in range[a][0]..range[a][1] per axis, rounded to 0.001 deg
 * (what the G-code line and the CSV carry), from a seeded generator so that
 * a seed gives the same plan on every machine. Returns 0 or -1 with err. */
int rig_plan_random(int n, const double range[3][2], unsigned long long seed, rig_pose **poses,
                    char *err);

/* Parse "A,B" into lo, hi (lo <= hi). Returns 0 or -1. */
int rig_parse_range(const char *s, double *lo, double *hi);

#endif
