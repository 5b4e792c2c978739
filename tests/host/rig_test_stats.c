/* Unit tests of the rig's metrics (conventions.md), plans and report files
 * (host/rig/rig_stats.c, rig_plan.c, rig_report.c). */
#define _DEFAULT_SOURCE
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "conv_vectors.h"
#include "rig_plan.h"
#include "rig_report.h"
#include "rig_stats.h"
#include "sp_euler.h"

static void test_wrap(void **state)
{
    (void)state;
    assert_float_equal(rig_wrap_deg(190), -170, 1e-12);
    assert_float_equal(rig_wrap_deg(-190), 170, 1e-12);
    assert_float_equal(rig_wrap_deg(180), 180, 1e-12); /* (-180, 180] */
    assert_float_equal(rig_wrap_deg(-180), 180, 1e-12);
    assert_float_equal(rig_wrap_deg(540), 180, 1e-12);
    assert_float_equal(rig_wrap_deg(359.9), -0.1, 1e-9);
    assert_float_equal(rig_wrap_deg(-0.5), -0.5, 1e-12);
    assert_float_equal(rig_wrap_deg(720.25), 0.25, 1e-9);
}

static void test_errors_wrapped(void **state)
{
    double e[3], pred[3] = {179, -10, 0.5}, truth[3] = {-179, 350, -0.25};
    (void)state;
    rig_pose_errors(pred, truth, e);
    assert_float_equal(e[0], 2, 1e-9);
    assert_float_equal(e[1], 0, 1e-9);
    assert_float_equal(e[2], 0.75, 1e-9);
}

/* Every case of tests/data/conventions_vectors.json, pose -> R: the header is
 * generated from that file when the test is built (host/rig/Makefile), so the
 * vectors have one source. */
static void test_matrix_vectors(void **state)
{
    size_t c;
    int i, k;
    (void)state;
    assert_int_equal(CONV_N_CASES, 7); /* docs/conventions.md, "Test vectors" */
    for (c = 0; c < CONV_N_CASES; c++) {
        double R[3][3];
        sp_euler_to_matrix(conv_cases[c].pose, R);
        for (i = 0; i < 3; i++)
            for (k = 0; k < 3; k++) assert_float_equal(R[i][k], conv_cases[c].R[i][k], 1e-8);
    }
}

static void test_geodesic(void **state)
{
    double a[3] = {0, 0, 0}, b[3] = {10, 0, 0}, c[3] = {12, -27, 6}, d[3] = {12, -27, 6 + 360};
    (void)state;
    assert_float_equal(rig_geodesic_deg(a, a), 0, 1e-6);
    assert_float_equal(rig_geodesic_deg(a, b), 10, 1e-9);
    assert_float_equal(rig_geodesic_deg(c, d), 0, 1e-5);
    /* Symmetric, and at most the sum of the per-axis errors. */
    assert_float_equal(rig_geodesic_deg(b, c), rig_geodesic_deg(c, b), 1e-9);
    assert_true(rig_geodesic_deg(b, c) <= 2 + 27 + 6 + 1e-9);
}

/* The paper's Table 1, Texture_3_color: Err 0.284, 0.367, 0.596 and Std 0.211,
 * 0.242, 0.466 give MAE 0.416 and RMSE 0.545. Two samples Err +- Std per axis
 * have exactly that mean and population deviation. */
static void test_paper_table1(void **state)
{
    static const double err[3] = {0.284, 0.367, 0.596}, sd[3] = {0.211, 0.242, 0.466};
    double e[2 * 3];
    rig_summary s;
    int a;
    (void)state;
    for (a = 0; a < 3; a++) {
        e[a] = err[a] + sd[a];
        e[3 + a] = err[a] - sd[a];
    }
    assert_int_equal(rig_summarise(e, NULL, 2, &s), 0);
    for (a = 0; a < 3; a++) {
        assert_float_equal(s.axis[a].err, err[a], 1e-12);
        assert_float_equal(s.axis[a].std, sd[a], 1e-12);
        assert_float_equal(s.axis[a].rmse * s.axis[a].rmse, err[a] * err[a] + sd[a] * sd[a], 1e-12);
        assert_float_equal(s.axis[a].max, err[a] + sd[a], 1e-12);
    }
    assert_float_equal(s.mae, 0.416, 0.0005);
    assert_float_equal(s.rmse, 0.545, 0.0005);
}

static void test_quartiles(void **state)
{
    /* One axis 1..9 and an outlier 100: numpy.percentile gives these. */
    double e[10 * 3];
    rig_summary s;
    int i;
    (void)state;
    for (i = 0; i < 10; i++) {
        e[3 * i] = i < 9 ? i + 1 : 100;
        e[3 * i + 1] = e[3 * i + 2] = 1;
    }
    assert_int_equal(rig_summarise(e, NULL, 10, &s), 0);
    assert_float_equal(s.axis[0].q1, 3.25, 1e-12);
    assert_float_equal(s.axis[0].median, 5.5, 1e-12);
    assert_float_equal(s.axis[0].q3, 7.75, 1e-12);
    assert_float_equal(s.axis[0].whisk_lo, 1, 1e-12);
    assert_float_equal(s.axis[0].whisk_hi, 9, 1e-12); /* 100 is an outlier */
    assert_float_equal(s.axis[0].max, 100, 1e-12);
    assert_float_equal(s.axis[1].std, 0, 1e-12);
    assert_int_equal(rig_summarise(e, NULL, 0, &s), 0);
    assert_int_equal(s.n, 0);
}

static char *write_tmp(const char *text)
{
    static char path[64];
    int fd;
    snprintf(path, sizeof(path), "/tmp/rig_plan_XXXXXX");
    fd = mkstemp(path);
    assert_true(fd >= 0);
    assert_int_equal(write(fd, text, strlen(text)), (ssize_t)strlen(text));
    close(fd);
    return path;
}

static void test_plan_load(void **state)
{
    rig_pose *p;
    char err[RIG_ERR_LEN];
    int n;
    char *path = write_tmp("x,y,z\n# comment\n\n1,2,3\r\n -4.5 , 0 ,30\n7.125,-0.001,6\n");
    (void)state;
    assert_int_equal(rig_plan_load(path, &p, &n, err), 0);
    assert_int_equal(n, 3);
    assert_float_equal(p[1].xyz[0], -4.5, 1e-12);
    assert_float_equal(p[2].xyz[1], -0.001, 1e-12);
    free(p);
    unlink(path);
}

static void test_plan_errors(void **state)
{
    static const char *bad[] = {
        "1,2\n",
        "1,2,3,4\n",
        "1,2,x\n",
        "x,y,z\nX,Y,Z\n",
        "1,2,3\nheader,late,here\n",
        "nan,0,0\n",
        "",
        "# only a comment\n",
        "1;2;3\n",
    };
    size_t i;
    rig_pose *p;
    char err[RIG_ERR_LEN];
    int n;
    (void)state;
    for (i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        char *path = write_tmp(bad[i]);
        err[0] = '\0';
        assert_int_equal(rig_plan_load(path, &p, &n, err), -1);
        assert_non_null(strstr(err, path)); /* the message names the file */
        assert_null(p);
        unlink(path);
    }
    assert_int_equal(rig_plan_load("/nonexistent/plan.csv", &p, &n, err), -1);
    assert_non_null(strstr(err, "/nonexistent/plan.csv"));
}

static void test_plan_random(void **state)
{
    const double range[3][2] = {{-30, 30}, {-10, 5}, {0, 0}};
    rig_pose *a, *b;
    char err[RIG_ERR_LEN];
    int i, k;
    (void)state;
    assert_int_equal(rig_plan_random(500, range, 42, &a, err), 0);
    assert_int_equal(rig_plan_random(500, range, 42, &b, err), 0);
    assert_memory_equal(a, b, 500 * sizeof(rig_pose));
    for (i = 0; i < 500; i++) {
        for (k = 0; k < 3; k++) {
            assert_true(a[i].xyz[k] >= range[k][0] && a[i].xyz[k] <= range[k][1]);
            assert_float_equal(a[i].xyz[k] * 1000, round(a[i].xyz[k] * 1000), 1e-6);
        }
    }
    free(b);
    assert_int_equal(rig_plan_random(500, range, 43, &b, err), 0);
    assert_true(memcmp(a, b, 500 * sizeof(rig_pose)) != 0);
    free(a);
    free(b);
    assert_int_equal(rig_plan_random(0, range, 1, &a, err), -1);
}

static void test_parse_range(void **state)
{
    double lo, hi;
    (void)state;
    assert_int_equal(rig_parse_range("-30,30", &lo, &hi), 0);
    assert_float_equal(lo, -30, 0);
    assert_float_equal(hi, 30, 0);
    assert_int_equal(rig_parse_range("5,-5", &lo, &hi), -1);
    assert_int_equal(rig_parse_range("5", &lo, &hi), -1);
    assert_int_equal(rig_parse_range("1,2,3", &lo, &hi), -1);
    assert_int_equal(rig_parse_range("a,b", &lo, &hi), -1);
}

static void test_report_files(void **state)
{
    rig_row rows[3];
    rig_results s;
    rig_run_info info = {"/dev/pts/9", "unix:/tmp/cam",        "m.onnx", "test", 3, 2, 1, NULL, 1.5,
                         100,          "2025-01-01T00:00:00Z", NULL,     0};
    char err[RIG_ERR_LEN], dir[64], path[128], buf[8192];
    FILE *f;
    size_t len;
    int i;
    (void)state;
    memset(rows, 0, sizeof(rows));
    for (i = 0; i < 3; i++) {
        rows[i].index = i;
        rows[i].cmd[0] = i;
        rows[i].ok = i != 1;
        rows[i].err[0] = i + 0.5;
        snprintf(rows[i].status, sizeof(rows[i].status), "%s",
                 i == 1 ? "pi_infer_frame: no sphere, \"found\"" : "ok");
    }
    snprintf(dir, sizeof(dir), "/tmp/rig_report_XXXXXX");
    assert_non_null(mkdtemp(dir));
    assert_int_equal(rig_summarise_rows(rows, 3, &s, err), 0);
    assert_int_equal(s.all.n, 2);
    assert_float_equal(s.all.axis[0].err, (0.5 + 2.5) / 2, 1e-12);
    /* A model without its texture judges nothing: every measured pose counts. */
    assert_int_equal(s.judged, 0);
    assert_int_equal(s.flagged, 0);
    assert_int_equal(s.confident.n, 2);
    assert_float_equal(s.confident.axis[0].err, s.all.axis[0].err, 1e-12);
    snprintf(path, sizeof(path), "%s/poses.csv", dir);
    assert_int_equal(rig_write_csv(path, rows, 3, err), 0);
    f = fopen(path, "r");
    assert_non_null(f);
    len = fread(buf, 1, sizeof(buf) - 1, f);
    buf[len] = '\0';
    fclose(f);
    assert_non_null(strstr(buf, "index,cmd_x,cmd_y,cmd_z,"));
    assert_non_null(strstr(buf, ",sphere_r,confident,residual,"));
    assert_non_null(strstr(buf, ",status,note,frame\n"));
    assert_non_null(strstr(buf, "\"pi_infer_frame: no sphere, \"\"found\"\"\""));
    unlink(path);
    snprintf(path, sizeof(path), "%s/summary.md", dir);
    assert_int_equal(rig_write_summary_md(path, &info, &s, rows, 3, err), 0);
    unlink(path);
    snprintf(path, sizeof(path), "%s/boxplot.svg", dir);
    assert_int_equal(rig_write_boxplot_svg(path, &s, rows, 3, err), 0);
    unlink(path);
    /* A folder that does not exist: an error naming the file, no crash. */
    assert_int_equal(rig_write_csv("/nonexistent/dir/poses.csv", rows, 3, err), -1);
    assert_non_null(strstr(err, "/nonexistent/dir/poses.csv"));
    rmdir(dir);
}

/* Read a whole (small) file into buf. */
static void slurp(const char *path, char *buf, size_t len)
{
    FILE *f = fopen(path, "r");
    size_t k;
    assert_non_null(f);
    k = fread(buf, 1, len - 1, f);
    buf[k] = '\0';
    fclose(f);
}

/* The CSV line of pose `index` (after the header), copied into line. */
static void csv_line(const char *buf, int index, char *line, size_t len)
{
    const char *p = strchr(buf, '\n');
    char want[16];
    size_t k;
    snprintf(want, sizeof(want), "%d,", index);
    for (; p && *p; p = strchr(p + 1, '\n'))
        if (strncmp(p + 1, want, strlen(want)) == 0) break;
    assert_non_null(p);
    p++;
    for (k = 0; p[k] && p[k] != '\n' && k + 1 < len; k++) line[k] = p[k];
    line[k] = '\0';
}

/* Five measured poses, one flagged, one flagged with no residual, one
 * failed: the flagged ones are left out of the confident statistics, listed
 * apart, and counted in the all-poses statistics. */
static void test_flagged_poses(void **state)
{
    rig_row rows[6];
    rig_results s;
    rig_run_info info = {"/dev/pts/9",
                         "unix:/tmp/cam",
                         "m.onnx",
                         "test",
                         6,
                         5,
                         1,
                         NULL,
                         1.5,
                         100,
                         "2025-01-01T00:00:00Z",
                         "{\"residual_max\": 0.1}",
                         0};
    char err[RIG_ERR_LEN], dir[64], path[128], buf[16384], line[1024], *text = NULL;
    size_t textlen = 0;
    FILE *f;
    int i;
    (void)state;
    memset(rows, 0, sizeof(rows));
    for (i = 0; i < 6; i++) {
        int k;
        rows[i].index = i;
        rows[i].cmd[0] = i;
        rows[i].ok = i != 4;
        rows[i].has_conf = rows[i].ok;
        rows[i].confident = i != 1 && i != 3;
        rows[i].residual = i == 3 ? NAN : 0.01 * (i + 1);
        for (k = 0; k < 3; k++) rows[i].err[k] = 0.1 * (i + 1) + k;
        rows[i].geo = 0.2 * (i + 1);
        snprintf(rows[i].status, sizeof(rows[i].status), "%s", rows[i].ok ? "ok" : "camera: gone");
    }
    rows[1].err[0] = 40; /* far off, and flagged: must not reach the table */
    rows[1].residual = 0.9;
    snprintf(rows[1].note, sizeof(rows[1].note),
             "poor alignment (residual 0.900 > 0.100): another texture");
    snprintf(rows[3].note, sizeof(rows[3].note), "refine: circle too small or outside the frame");
    assert_int_equal(rig_row_flagged(&rows[1]), 1);
    assert_int_equal(rig_row_flagged(&rows[0]), 0);
    assert_int_equal(rig_row_flagged(&rows[4]), 0); /* no estimate: failed, not flagged */

    assert_int_equal(rig_summarise_rows(rows, 6, &s, err), 0);
    assert_int_equal(s.measured, 5);
    assert_int_equal(s.judged, 5);
    assert_int_equal(s.flagged, 2);
    assert_int_equal(s.confident.n, 3); /* poses 0, 2, 5 */
    assert_int_equal(s.all.n, 5);
    assert_float_equal(s.confident.axis[0].err, (0.1 + 0.3 + 0.6) / 3, 1e-12);
    assert_float_equal(s.confident.axis[0].max, 0.6, 1e-12);
    assert_float_equal(s.confident.geo.err, (0.2 + 0.6 + 1.2) / 3, 1e-12);
    assert_float_equal(s.all.axis[0].err, (0.1 + 40 + 0.3 + 0.4 + 0.6) / 5, 1e-12);
    assert_float_equal(s.all.axis[0].max, 40, 1e-12);

    snprintf(dir, sizeof(dir), "/tmp/rig_report_XXXXXX");
    assert_non_null(mkdtemp(dir));
    snprintf(path, sizeof(path), "%s/poses.csv", dir);
    assert_int_equal(rig_write_csv(path, rows, 6, err), 0);
    slurp(path, buf, sizeof(buf));
    csv_line(buf, 0, line, sizeof(line));
    assert_non_null(strstr(line, ",true,0.01000,"));
    assert_non_null(strstr(line, ",\"ok\",\"\","));
    csv_line(buf, 1, line, sizeof(line));
    assert_non_null(strstr(line, ",false,0.90000,"));
    assert_non_null(
        strstr(line, ",\"ok\",\"poor alignment (residual 0.900 > 0.100): another texture\","));
    csv_line(buf, 3, line, sizeof(line));
    assert_non_null(strstr(line, ",false,,")); /* refinement could not run: no residual */
    csv_line(buf, 4, line, sizeof(line));
    assert_non_null(strstr(line, ",,,")); /* no estimate: nothing judged */
    assert_null(strstr(line, "true"));
    assert_null(strstr(line, "false"));
    unlink(path);

    snprintf(path, sizeof(path), "%s/summary.md", dir);
    assert_int_equal(rig_write_summary_md(path, &info, &s, rows, 6, err), 0);
    slurp(path, buf, sizeof(buf));
    assert_non_null(strstr(buf, "| measured: confident / flagged | 3 / 2 |"));
    assert_non_null(strstr(buf, "## Flagged poses (not confident, 2)"));
    assert_non_null(strstr(buf, "| 1 | 1.000, 0.000, 0.000 |"));
    assert_non_null(
        strstr(buf, "| 0.9000 | poor alignment (residual 0.900 > 0.100): another texture |"));
    assert_non_null(strstr(buf, "| n/a | refine: circle too small"));
    assert_null(strstr(buf, "| 0 | 0.000, 0.000, 0.000 |")); /* a confident pose is not listed */
    /* The confident table first (max 0.600), then all poses (max 40.000). */
    assert_non_null(strstr(buf, "| X-axis | 0.333 | "));
    assert_true(strstr(buf, "| X-axis | 0.333 | ") < strstr(buf, "all 5 measured poses"));
    assert_non_null(strstr(strstr(buf, "all 5 measured poses"), "| X-axis | 8.280 | "));
    assert_non_null(strstr(strstr(buf, "all 5 measured poses"), "| 40.000 |"));
    unlink(path);

    f = open_memstream(&text, &textlen);
    assert_non_null(f);
    rig_print_summary(f, &info, &s, rows, 6);
    fclose(f);
    assert_non_null(strstr(
        text, "Error analysis of 3 confident pose(s) (degrees; 6 planned, 1 failed, 2 flagged)"));
    assert_non_null(
        strstr(text, "Flagged, left out of the table above: 2 of 5 measured pose(s): 1, 3\n"));
    assert_non_null(strstr(
        text, "  pose 1 cmd (1.000, 0.000, 0.000) geodesic 0.400 residual 0.9000: poor alignment"));
    assert_non_null(strstr(text, "All 5 measured pose(s), flagged included"));
    /* The first X-axis row is the confident one. */
    assert_non_null(strstr(text, "X-axis          0.333     0.205     0.392     0.600\n"));
    assert_true(strstr(text, "X-axis          0.333") < strstr(text, "All 5 measured"));
    free(text);

    snprintf(path, sizeof(path), "%s/boxplot.svg", dir);
    assert_int_equal(rig_write_boxplot_svg(path, &s, rows, 6, err), 0);
    slurp(path, buf, sizeof(buf));
    assert_non_null(strstr(buf, "n = 3 confident"));
    assert_non_null(strstr(buf, "<title>pose 1 (flagged): 40.000</title>"));
    unlink(path);

    /* Nothing flagged: one table, said to cover every pose. */
    rows[1].confident = rows[3].confident = 1;
    assert_int_equal(rig_summarise_rows(rows, 6, &s, err), 0);
    assert_int_equal(s.flagged, 0);
    text = NULL;
    f = open_memstream(&text, &textlen);
    rig_print_summary(f, &info, &s, rows, 6);
    fclose(f);
    assert_non_null(strstr(text, "Flagged: none"));
    assert_null(strstr(text, "All 5 measured"));
    free(text);
    rmdir(dir);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_wrap),           cmocka_unit_test(test_errors_wrapped),
        cmocka_unit_test(test_matrix_vectors), cmocka_unit_test(test_geodesic),
        cmocka_unit_test(test_paper_table1),   cmocka_unit_test(test_quartiles),
        cmocka_unit_test(test_plan_load),      cmocka_unit_test(test_plan_errors),
        cmocka_unit_test(test_plan_random),    cmocka_unit_test(test_parse_range),
        cmocka_unit_test(test_report_files),   cmocka_unit_test(test_flagged_poses),
    };
    return cmocka_run_group_tests_name("rig_stats", tests, NULL, NULL);
}
