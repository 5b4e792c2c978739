/* rig_report.c -- see rig_report.h. */
#define _DEFAULT_SOURCE
#include "rig_report.h"
#include "rig_plan.h"

#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* Open path.tmp for writing; rig_commit renames it over path. */
static FILE *atomic_open(const char *path, char *tmp, size_t tmplen, char *err)
{
    FILE *f;
    snprintf(tmp, tmplen, "%s.tmp", path);
    if (!(f = fopen(tmp, "w"))) rig_seterr(err, "fopen(%s): %s", tmp, strerror(errno));
    return f;
}

static int atomic_commit(FILE *f, const char *tmp, const char *path, char *err)
{
    /* fsync before rename: after a crash the file is the old or the new
     * one, never an empty new name. */
    if (fflush(f) != 0 || ferror(f) || fsync(fileno(f)) != 0) {
        rig_seterr(err, "write(%s): %s", tmp, strerror(errno));
        fclose(f);
        unlink(tmp);
        return -1;
    }
    if (fclose(f) != 0) {
        rig_seterr(err, "fclose(%s): %s", tmp, strerror(errno));
        unlink(tmp);
        return -1;
    }
    if (rename(tmp, path) != 0) {
        rig_seterr(err, "rename(%s): %s", path, strerror(errno));
        unlink(tmp);
        return -1;
    }
    return 0;
}

/* CSV field: the status text may hold commas or quotes. */
static void csv_text(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"') fputc('"', f);
        fputc(*s == '\n' || *s == '\r' ? ' ' : *s, f);
    }
    fputc('"', f);
}

int rig_row_flagged(const rig_row *row)
{
    return row->ok && row->has_conf && !row->confident;
}

int rig_write_csv(const char *path, const rig_row *rows, int n, char *err)
{
    char tmp[4096];
    FILE *f = atomic_open(path, tmp, sizeof(tmp), err);
    int i;
    if (!f) return -1;
    fputs("index,cmd_x,cmd_y,cmd_z,mpos_x,mpos_y,mpos_z,wpos_x,wpos_y,wpos_z,"
          "est_x,est_y,est_z,err_x,err_y,err_z,geodesic,"
          "sphere_cx,sphere_cy,sphere_r,confident,residual,"
          "move_ms,settle_ms,grab_ms,decode_ms,preprocess_ms,locate_ms,infer_ms,refine_ms,pose_ms,"
          "status,"
          "note,frame\n",
          f);
    for (i = 0; i < n; i++) {
        const rig_row *r = &rows[i];
        fprintf(f, "%d,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,%.3f,", r->index, r->cmd[0],
                r->cmd[1], r->cmd[2], r->mpos[0], r->mpos[1], r->mpos[2], r->wpos[0], r->wpos[1],
                r->wpos[2]);
        if (r->ok)
            fprintf(f, "%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.3f,%.3f,%.3f,", r->est[0], r->est[1],
                    r->est[2], r->err[0], r->err[1], r->err[2], r->geo, r->cx, r->cy, r->r);
        else
            fputs(",,,,,,,,,,", f);
        /* Empty when nothing was judged: no estimate, or a model without
         * its texture. A residual is NaN when refinement could not run. */
        if (r->ok && r->has_conf) {
            fputs(r->confident ? "true," : "false,", f);
            if (isfinite(r->residual)) fprintf(f, "%.5f", r->residual);
            fputc(',', f);
        } else {
            fputs(",,", f);
        }
        fprintf(f, "%.1f,%.1f,%.1f,%.2f,%.2f,%.2f,%.2f,%.2f,%.1f,", r->move_ms, r->settle_ms,
                r->grab_ms, r->decode_ms, r->preprocess_ms, r->locate_ms, r->infer_ms, r->refine_ms,
                r->pose_ms);
        csv_text(f, r->status);
        fputc(',', f);
        csv_text(f, r->ok && r->has_conf ? r->note : "");
        fputc(',', f);
        fputs(r->frame, f);
        fputc('\n', f);
    }
    return atomic_commit(f, tmp, path, err);
}

/* Statistics over the measured rows, all of them or only those not flagged. */
static int summarise_some(const rig_row *rows, int n, int confident_only, rig_summary *s, char *err)
{
    double *e = malloc((size_t)(n > 0 ? n : 1) * 3 * sizeof(double));
    double *g = malloc((size_t)(n > 0 ? n : 1) * sizeof(double));
    int i, k = 0, rc = 0;
    if (!e || !g) {
        rig_seterr(err, "rig_summarise_rows: out of memory");
        rc = -1;
        goto out;
    }
    for (i = 0; i < n; i++) {
        if (!rows[i].ok || (confident_only && rig_row_flagged(&rows[i]))) continue;
        memcpy(e + 3 * k, rows[i].err, 3 * sizeof(double));
        g[k] = rows[i].geo;
        k++;
    }
    if (rig_summarise(e, g, k, s) != 0) {
        rig_seterr(err, "rig_summarise: out of memory");
        rc = -1;
    }
out:
    free(e);
    free(g);
    return rc;
}

int rig_summarise_rows(const rig_row *rows, int n, rig_results *res, char *err)
{
    int i;
    memset(res, 0, sizeof(*res));
    for (i = 0; i < n; i++) {
        if (!rows[i].ok) continue;
        res->measured++;
        res->judged += rows[i].has_conf;
        res->flagged += rig_row_flagged(&rows[i]);
    }
    if (summarise_some(rows, n, 1, &res->confident, err) != 0) return -1;
    return summarise_some(rows, n, 0, &res->all, err);
}

static const char *axis_name[3] = {"X-axis", "Y-axis", "Z-axis"};

static void print_table(FILE *out, const rig_summary *s)
{
    int a;
    fprintf(out, "%-10s %10s %9s %9s %9s\n", "Parameter", "Mean Error", "Std", "RMSE", "Maximum");
    for (a = 0; a < 3; a++)
        fprintf(out, "%-10s %10.3f %9.3f %9.3f %9.3f\n", axis_name[a], s->axis[a].err,
                s->axis[a].std, s->axis[a].rmse, s->axis[a].max);
    fprintf(out, "%-10s %10.3f %9.3f %9.3f %9.3f\n", "Geodesic", s->geo.err, s->geo.std,
            s->geo.rmse, s->geo.max);
    fprintf(out, "MAE %.3f  RMSE %.3f\n", s->mae, s->rmse);
}

/* Residual as text: "n/a" when refinement could not run. */
static const char *fmt_residual(char *buf, size_t len, double v)
{
    if (isfinite(v))
        snprintf(buf, len, "%.4f", v);
    else
        snprintf(buf, len, "n/a");
    return buf;
}

#define PRINT_FLAGGED_MAX 10 /* flagged poses explained on stdout; summary.md has them all */

void rig_print_summary(FILE *out, const rig_run_info *info, const rig_results *res,
                       const rig_row *rows, int n)
{
    const char *stop_sep = info->stopped ? "; stopped: " : "",
               *stop = info->stopped ? info->stopped : "";
    int i, shown = 0;
    if (res->judged == 0) {
        /* Nothing judged: one table, and why it is not split. */
        fprintf(out, "Error analysis of %d pose(s) (degrees; %d planned, %d failed%s%s)\n",
                res->all.n, info->planned, info->failed, stop_sep, stop);
        print_table(out, &res->all);
        if (res->measured)
            fprintf(
                out,
                "Confidence: none (the model carries no texture; every measured pose counted)\n");
        return;
    }
    fprintf(
        out,
        "Error analysis of %d confident pose(s) (degrees; %d planned, %d failed, %d flagged%s%s)\n",
        res->confident.n, info->planned, info->failed, res->flagged, stop_sep, stop);
    print_table(out, &res->confident);
    if (res->flagged == 0) {
        fprintf(out, "Flagged: none (the table covers every measured pose)\n");
        return;
    }
    fprintf(out, "Flagged, left out of the table above: %d of %d measured pose(s): ", res->flagged,
            res->measured);
    for (i = 0; i < n; i++)
        if (rig_row_flagged(&rows[i])) fprintf(out, "%s%d", shown++ ? ", " : "", rows[i].index);
    fputc('\n', out);
    for (i = 0, shown = 0; i < n && shown < PRINT_FLAGGED_MAX; i++) {
        char rb[32];
        if (!rig_row_flagged(&rows[i])) continue;
        fprintf(out, "  pose %d cmd (%.3f, %.3f, %.3f) geodesic %.3f residual %s: %s\n",
                rows[i].index, rows[i].cmd[0], rows[i].cmd[1], rows[i].cmd[2], rows[i].geo,
                fmt_residual(rb, sizeof(rb), rows[i].residual), rows[i].note);
        shown++;
    }
    if (res->flagged > shown)
        fprintf(out, "  ... and %d more (summary.md)\n", res->flagged - shown);
    fprintf(out, "All %d measured pose(s), flagged included (degrees)\n", res->all.n);
    print_table(out, &res->all);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* p50 and p99 of one timing column over the measured rows. */
static void timing(const rig_row *rows, int n, size_t off, double *p50, double *p99)
{
    double *v = malloc((size_t)(n > 0 ? n : 1) * sizeof(double));
    int i, k = 0;
    *p50 = *p99 = 0;
    if (!v) return;
    for (i = 0; i < n; i++)
        if (rows[i].ok) v[k++] = *(const double *)((const char *)&rows[i] + off);
    qsort(v, (size_t)k, sizeof(double), cmp_double);
    *p50 = rig_percentile(v, k, 50);
    *p99 = rig_percentile(v, k, 99);
    free(v);
}

static void md_table(FILE *f, const rig_summary *s)
{
    int a;
    fprintf(
        f,
        "| Parameter | Mean Error | Std | RMSE | Maximum |\n| --- | ---: | ---: | ---: | ---: |\n");
    for (a = 0; a < 3; a++)
        fprintf(f, "| %s | %.3f | %.3f | %.3f | %.3f |\n", axis_name[a], s->axis[a].err,
                s->axis[a].std, s->axis[a].rmse, s->axis[a].max);
    fprintf(f, "| Geodesic | %.3f | %.3f | %.3f | %.3f |\n", s->geo.err, s->geo.std, s->geo.rmse,
            s->geo.max);
}

/* A note in a Markdown table cell: no '|' or line breaks. */
static void md_cell(FILE *f, const char *s)
{
    for (; *s; s++) fputc(*s == '|' ? '/' : *s == '\n' || *s == '\r' ? ' ' : *s, f);
}

#define MD_FLAGGED_MAX 200 /* flagged poses listed in summary.md; poses.csv has them all */

int rig_write_summary_md(const char *path, const rig_run_info *info, const rig_results *res,
                         const rig_row *rows, int n, char *err)
{
    static const struct {
        const char *name;
        size_t off;
    } cols[] = {
        {"move + wait Idle", offsetof(rig_row, move_ms)},
        {"settle", offsetof(rig_row, settle_ms)},
        {"grab", offsetof(rig_row, grab_ms)},
        {"decode", offsetof(rig_row, decode_ms)},
        {"preprocess", offsetof(rig_row, preprocess_ms)},
        {"of it, localisation", offsetof(rig_row, locate_ms)},
        {"inference", offsetof(rig_row, infer_ms)},
        {"refinement", offsetof(rig_row, refine_ms)},
        {"whole pose", offsetof(rig_row, pose_ms)},
    };
    char tmp[4096];
    FILE *f = atomic_open(path, tmp, sizeof(tmp), err);
    size_t c;
    int i;
    if (!f) return -1;
    fprintf(f, "# Rig experiment\n\n");
    fprintf(f, "| | |\n| --- | --- |\n");
    fprintf(f,
            "| started (UTC) | %s |\n| stage port | `%s` |\n| camera | `%s` |\n| model | `%s` |\n",
            info->started, info->port, info->camera, info->model);
    fprintf(f, "| plan | %s |\n| poses planned / measured / failed | %d / %d / %d |\n", info->plan,
            info->planned, res->measured, info->failed);
    if (res->judged)
        fprintf(
            f,
            "| measured: confident / flagged | %d / %d |\n| confidence thresholds | %s%s%s%s |\n",
            res->confident.n, res->flagged, info->confidence ? "`" : "",
            info->confidence ? info->confidence : "the library's defaults",
            info->confidence ? "`" : "", info->no_refine ? " (unrefined: `--no-refine`)" : "");
    else if (res->measured)
        fprintf(f, "| confidence | none: the model carries no texture (docs/refine.md) |\n");
    fprintf(f, "| settle time | %d ms |\n| run time | %.1f s |\n", info->settle_ms,
            info->elapsed_s);
    if (info->stopped) fprintf(f, "| stopped early | %s |\n", info->stopped);
    fprintf(f,
            "\n## Error analysis (degrees)%s\n\n"
            "Errors e = |wrap(estimate - commanded)| per axis; Err the mean, Std the population\n"
            "standard deviation, RMSE = sqrt(mean(e^2)) (docs/conventions.md).\n",
            res->judged ? ", confident poses" : "");
    if (res->judged)
        fprintf(f,
                "Over the %d confident pose(s); the %d flagged pose(s) are listed below and "
                "counted in the\n"
                "all-poses table after them.\n",
                res->confident.n, res->flagged);
    fputc('\n', f);
    md_table(f, &res->confident);
    fprintf(f, "\nMAE %.3f, RMSE %.3f over %s poses and axes.\n", res->confident.mae,
            res->confident.rmse, res->judged ? "the confident" : "all measured");
    fprintf(f, "\n![box plot of the per-axis errors](boxplot.svg)\n");
    if (res->flagged) {
        int shown = 0;
        char rb[32];
        fprintf(f,
                "\n## Flagged poses (not confident, %d)\n\n"
                "The estimate is reported but the model does not vouch for it (docs/refine.md).\n\n"
                "| pose | commanded | estimate | geodesic | residual | note |\n"
                "| ---: | --- | --- | ---: | ---: | --- |\n",
                res->flagged);
        for (i = 0; i < n && shown < MD_FLAGGED_MAX; i++) {
            const rig_row *r = &rows[i];
            if (!rig_row_flagged(r)) continue;
            fprintf(f, "| %d | %.3f, %.3f, %.3f | %.3f, %.3f, %.3f | %.3f | %s | ", r->index,
                    r->cmd[0], r->cmd[1], r->cmd[2], r->est[0], r->est[1], r->est[2], r->geo,
                    fmt_residual(rb, sizeof(rb), r->residual));
            md_cell(f, r->note);
            fputs(" |\n", f);
            shown++;
        }
        if (res->flagged > shown)
            fprintf(f, "\n... and %d more (poses.csv).\n", res->flagged - shown);
        fprintf(f, "\n## Error analysis (degrees), all %d measured poses, flagged included\n\n",
                res->all.n);
        md_table(f, &res->all);
        fprintf(f, "\nMAE %.3f, RMSE %.3f over all measured poses and axes.\n", res->all.mae,
                res->all.rmse);
    }
    fprintf(f, "\n## Timings per pose (ms, measured poses)\n\n| step | p50 | p99 |\n| --- | ---: | "
               "---: |\n");
    for (c = 0; c < sizeof(cols) / sizeof(cols[0]); c++) {
        double p50, p99;
        timing(rows, n, cols[c].off, &p50, &p99);
        fprintf(f, "| %s | %.1f | %.1f |\n", cols[c].name, p50, p99);
    }
    if (info->failed) {
        int shown = 0;
        fprintf(f, "\n## Poses without an estimate\n\n");
        for (i = 0; i < n && shown < 20; i++) {
            if (rows[i].ok) continue;
            fprintf(f, "- pose %d (%.3f, %.3f, %.3f): %s\n", rows[i].index, rows[i].cmd[0],
                    rows[i].cmd[1], rows[i].cmd[2], rows[i].status);
            shown++;
        }
        if (info->failed > shown)
            fprintf(f, "- ... and %d more (poses.csv)\n", info->failed - shown);
    }
    return atomic_commit(f, tmp, path, err);
}

int rig_write_boxplot_svg(const char *path, const rig_results *res, const rig_row *rows, int n,
                          char *err)
{
    static const char *names[4] = {"X", "Y", "Z", "geodesic"};
    static const char *fills[4] = {"#4e79a7", "#f28e2b", "#59a14f", "#9c9c9c"};
    const double W = 640, H = 420, L = 60, R = 20, T = 48, B = 50;
    const rig_summary *s = &res->confident;
    char tmp[4096];
    FILE *f;
    double top = 0, step, scale, bw;
    int a, i;

    /* The axis fits the confident poses: a flagged pose can be off by tens of
     * degrees and would flatten their boxes; it is drawn at the top instead. */
    for (a = 0; a < 3; a++)
        if (s->axis[a].max > top) top = s->axis[a].max;
    if (s->geo.max > top) top = s->geo.max;
    if (s->n == 0 && res->flagged)
        for (i = 0; i < n; i++)
            if (rig_row_flagged(&rows[i])) {
                for (a = 0; a < 3; a++) top = fmax(top, rows[i].err[a]);
                top = fmax(top, rows[i].geo);
            }
    /* A round axis top: 1, 2 or 5 times a power of ten, per tick. */
    {
        double raw = (top > 0 ? top : 1) / 5, p = pow(10, floor(log10(raw)));
        step = raw / p <= 1 ? p : raw / p <= 2 ? 2 * p : raw / p <= 5 ? 5 * p : 10 * p;
        top = step * ceil((top > 0 ? top : 1) / step);
    }
    scale = (H - T - B) / top;
    bw = (W - L - R) / 4;
    if (!(f = atomic_open(path, tmp, sizeof(tmp), err))) return -1;
    fprintf(f,
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
            "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\" font-size=\"12\">\n",
            W, H, W, H);
    fprintf(f, "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n");
    fprintf(f,
            "<text x=\"%.0f\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">"
            "Pose error per axis, degrees (n = %d%s)</text>\n",
            W / 2, s->n, res->judged ? " confident" : "");
    if (res->flagged)
        fprintf(f,
                "<text x=\"%.0f\" y=\"36\" text-anchor=\"middle\" fill=\"#c00\">"
                "%d flagged pose(s): red crosses, not in the boxes</text>\n",
                W / 2, res->flagged);
    for (i = 0; step * i <= top + 1e-9; i++) {
        double y = H - B - step * i * scale;
        fprintf(f, "<line x1=\"%.0f\" y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#ddd\"/>\n", L,
                y, W - R, y);
        fprintf(f, "<text x=\"%.0f\" y=\"%.1f\" text-anchor=\"end\">%g</text>\n", L - 6, y + 4,
                step * i);
    }
    fprintf(f, "<line x1=\"%.0f\" y1=\"%.0f\" x2=\"%.0f\" y2=\"%.0f\" stroke=\"black\"/>\n", L, T,
            L, H - B);
    fprintf(f,
            "<text transform=\"translate(16,%.0f) rotate(-90)\" text-anchor=\"middle\">"
            "|error| (deg)</text>\n",
            (H - B + T) / 2);
    for (a = 0; a < 4; a++) {
        const rig_axis_stats *st = a < 3 ? &s->axis[a] : &s->geo;
        double cx = L + bw * (a + 0.5), hw = bw * 0.25;
#define Y(v) (H - B - (v)*scale)
        if (s->n > 0) {
            /* Whiskers, box (Q1..Q3), median, mean, and outliers as circles. */
            fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"black\"/>\n",
                    cx, Y(st->whisk_lo), cx, Y(st->q1));
            fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"black\"/>\n",
                    cx, Y(st->q3), cx, Y(st->whisk_hi));
            fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"black\"/>\n",
                    cx - hw / 2, Y(st->whisk_lo), cx + hw / 2, Y(st->whisk_lo));
            fprintf(f, "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"black\"/>\n",
                    cx - hw / 2, Y(st->whisk_hi), cx + hw / 2, Y(st->whisk_hi));
            fprintf(f,
                    "<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"%s\" "
                    "fill-opacity=\"0.6\" stroke=\"black\"/>\n",
                    cx - hw, Y(st->q3), 2 * hw, (st->q3 - st->q1) * scale, fills[a]);
            fprintf(f,
                    "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"black\" "
                    "stroke-width=\"2\"/>\n",
                    cx - hw, Y(st->median), cx + hw, Y(st->median));
            fprintf(
                f,
                "<path d=\"M %.1f %.1f l 5 5 l -5 5 l -5 -5 z\" fill=\"white\" stroke=\"black\">"
                "<title>mean %.3f</title></path>\n",
                cx, Y(st->err) - 5, st->err);
            for (i = 0; i < n; i++) {
                double v;
                if (!rows[i].ok || rig_row_flagged(&rows[i])) continue;
                v = a < 3 ? rows[i].err[a] : rows[i].geo;
                if (v < st->whisk_lo || v > st->whisk_hi)
                    fprintf(
                        f,
                        "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"3\" fill=\"none\" stroke=\"black\">"
                        "<title>pose %d: %.3f</title></circle>\n",
                        cx, Y(v), rows[i].index, v);
            }
        }
        /* Flagged poses beside the box; one beyond the axis sits at its top
         * with a caret, its value in the tooltip. */
        for (i = 0; i < n; i++) {
            double v, y, x = cx + hw + 10;
            if (!rig_row_flagged(&rows[i])) continue;
            v = a < 3 ? rows[i].err[a] : rows[i].geo;
            y = Y(v > top ? top : v);
            fprintf(
                f,
                "<path d=\"M %.1f %.1f l 6 6 m 0 -6 l -6 6\" stroke=\"#c00\" stroke-width=\"1.5\">"
                "<title>pose %d (flagged): %.3f</title></path>\n",
                x - 3, y - 3, rows[i].index, v);
            if (v > top)
                fprintf(f, "<path d=\"M %.1f %.1f l 4 -6 l 4 6\" fill=\"none\" stroke=\"#c00\"/>\n",
                        x - 4, y - 6);
        }
#undef Y
        fprintf(f, "<text x=\"%.1f\" y=\"%.0f\" text-anchor=\"middle\">%s</text>\n", cx, H - B + 18,
                names[a]);
    }
    fprintf(f,
            "<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\" fill=\"#555\">box: quartiles, "
            "line: median, diamond: mean, whiskers: 1.5 IQR</text>\n",
            W / 2, H - 12);
    fputs("</svg>\n", f);
    return atomic_commit(f, tmp, path, err);
}
