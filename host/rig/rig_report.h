/* rig_report.h -- the files a rig run writes: poses.csv, summary.md and the
 * box plot (boxplot.svg), plus the Table 3 style summary on a stream.
 * Every file is written whole to a temporary name and renamed, so a reader
 * (or a run stopped half-way) never sees half a file.
 * A pose the model flags (not confident, docs/refine.md) is reported apart:
 * the headline statistics are over the confident poses, the flagged ones are
 * counted and listed beside them, and the statistics over all measured poses
 * follow, so nothing is hidden. */
#ifndef RIG_REPORT_H
#define RIG_REPORT_H

#include <stdio.h>
#include "rig_stats.h"

#define RIG_STATUS_LEN 256
#define RIG_NOTE_LEN   160

typedef struct {
    int index;               /* 0-based position in the plan */
    double cmd[3];           /* commanded pose, degrees (the truth of the errors) */
    double mpos[3];          /* stage-reported machine position after the move */
    double wpos[3];          /* stage-reported work position after the move */
    double est[3];           /* estimate */
    double err[3];           /* |wrap(est - cmd)| per axis */
    double geo;              /* geodesic error, degrees */
    double cx, cy, r;        /* sphere found in the frame, pixels */
    int has_conf;            /* 1: the model judged the estimate (it carries its texture) */
    int confident;           /* with has_conf: 1 confident, 0 flagged */
    double residual;         /* with has_conf: alignment residual (NaN: refinement could not run) */
    char note[RIG_NOTE_LEN]; /* with has_conf and not confident: why, else "" */
    double move_ms, settle_ms, grab_ms, decode_ms, preprocess_ms, locate_ms, infer_ms, refine_ms,
        pose_ms;
    int ok;                      /* 1: estimate recorded; 0: see status */
    char status[RIG_STATUS_LEN]; /* "ok" or the reason this pose has no estimate */
    char frame[128];             /* saved frame, relative to the output folder, or "" */
} rig_row;

typedef struct {
    const char *port, *camera, *model, *plan;
    int planned, done, failed;
    const char *stopped; /* NULL, or why the run ended early */
    double elapsed_s;
    int settle_ms;
    char started[32];       /* UTC, ISO 8601 */
    const char *confidence; /* the model's thresholds (metadata spherepose.confidence), or NULL */
    int no_refine;          /* 1: the network's angles, judged unrefined (--no-refine) */
} rig_run_info;

/* Measured poses split by the model's judgement. A model without its
 * texture judges nothing: every measured pose then counts as confident
 * (judged == 0 says so). */
typedef struct {
    rig_summary confident; /* measured poses not flagged: the headline numbers */
    rig_summary all;       /* every measured pose, flagged included */
    int measured, judged, flagged;
} rig_results;

/* 1 when the row is measured and the model flagged it. */
int rig_row_flagged(const rig_row *row);

/* Write rows as CSV to path (atomically). Returns 0 or -1 with err. */
int rig_write_csv(const char *path, const rig_row *rows, int n, char *err);

/* Statistics over the measured rows (ok == 1): all of them, and those not
 * flagged. Returns 0 or -1 with err. */
int rig_summarise_rows(const rig_row *rows, int n, rig_results *res, char *err);

/* Table 3 style summary (plain text): confident poses, the flagged ones
 * listed, then all measured poses when any was flagged. */
void rig_print_summary(FILE *out, const rig_run_info *info, const rig_results *res,
                       const rig_row *rows, int n);

/* summary.md: the same tables in Markdown, with the run's facts, the flagged
 * poses and why, timings and the poses without an estimate. */
int rig_write_summary_md(const char *path, const rig_run_info *info, const rig_results *res,
                         const rig_row *rows, int n, char *err);

/* Box plot of the confident poses' per-axis errors (and the geodesic
 * error) as SVG, the flagged poses' errors drawn over it as red crosses. */
int rig_write_boxplot_svg(const char *path, const rig_results *res, const rig_row *rows, int n,
                          char *err);

#endif
