/* rig_report.h -- the files a rig run writes: poses.csv, summary.md and the
 * box plot (boxplot.svg), plus the Table 3 style summary on a stream.
 * Every file is written whole to a temporary name and renamed, so a reader
 * (or a run stopped half-way) never sees half a file. */
#ifndef RIG_REPORT_H
#define RIG_REPORT_H

#include <stdio.h>
#include "rig_stats.h"

#define RIG_STATUS_LEN 256

typedef struct {
    int index;                  /* 0-based position in the plan */
    double cmd[3];              /* commanded pose, degrees (the truth of the errors) */
    double mpos[3];             /* stage-reported machine position after the move */
    double wpos[3];             /* stage-reported work position after the move */
    double est[3];              /* estimate */
    double err[3];              /* |wrap(est - cmd)| per axis */
    double geo;                 /* geodesic error, degrees */
    double cx, cy, r;           /* sphere found in the frame, pixels */
    double move_ms, settle_ms, grab_ms, decode_ms, preprocess_ms, infer_ms, pose_ms;
    int ok;                     /* 1: estimate recorded; 0: see status */
    char status[RIG_STATUS_LEN];/* "ok" or the reason this pose has no estimate */
    char frame[128];            /* saved frame, relative to the output folder, or "" */
} rig_row;

typedef struct {
    const char *port, *camera, *model, *plan;
    int planned, done, failed;
    const char *stopped;        /* NULL, or why the run ended early */
    double elapsed_s;
    int settle_ms;
    char started[32];           /* UTC, ISO 8601 */
} rig_run_info;

/* Write rows as CSV to path (atomically). Returns 0 or -1 with err. */
int rig_write_csv(const char *path, const rig_row *rows, int n, char *err);

/* Statistics over the rows with ok == 1. Returns 0 or -1 with err. */
int rig_summarise_rows(const rig_row *rows, int n, rig_summary *s, char *err);

/* Table 3 style summary (plain text). */
void rig_print_summary(FILE *out, const rig_run_info *info, const rig_summary *s);

/* summary.md: the same table in Markdown, with the run's facts and timings. */
int rig_write_summary_md(const char *path, const rig_run_info *info, const rig_summary *s,
                         const rig_row *rows, int n, char *err);

/* Box plot of the per-axis errors (and the geodesic error) as SVG. */
int rig_write_boxplot_svg(const char *path, const rig_summary *s, const rig_row *rows, int n,
                          char *err);

#endif
