/* poserig -- the paper's section 4 experiment on a real or simulated rig.
 *
 * For each pose of a plan: move the stage, wait until Idle and a settle
 * time, grab a frame, estimate the orientation with libposeinfer, and record
 * commanded pose, stage-reported position, estimate, errors and timings.
 * Writes OUT/poses.csv after every pose, then OUT/summary.md, OUT/boxplot.svg
 * and a Table 3 style summary on stdout: over the poses the model is
 * confident of, with the flagged ones listed apart and the statistics over
 * all measured poses beside them. The stage port and the camera are
 * whatever the options name: the simulated rig (stagesim's pty and the
 * virtual camera's unix: socket) takes no special case here. */
#define _DEFAULT_SOURCE
#include <errno.h>
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "poseinfer.h"
#include "rig_plan.h"
#include "rig_report.h"
#include "rig_stats.h"
#include "stage.h"

#define EXIT_SOME_FAILED 1
#define EXIT_USAGE       2

static volatile sig_atomic_t stop_signal;

static void on_signal(int sig)
{
    stop_signal = sig;
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000.0 + ts.tv_nsec / 1e6;
}

static void usage(FILE *f)
{
    fputs(
        "usage: poserig --camera SPEC --model MODEL.onnx (--plan FILE.csv | --random N) [options]\n"
        "\n"
        "Moves the stage through the plan; at each pose grabs a frame, estimates the\n"
        "sphere's orientation and records it; writes OUT/poses.csv, OUT/summary.md,\n"
        "OUT/boxplot.svg and prints a Table 3 style error summary (degrees). A model that\n"
        "carries its texture refines and judges every estimate (docs/refine.md): the summary\n"
        "is over the confident poses, the flagged ones listed apart, then over all poses.\n"
        "\n"
        "  --port PATH|auto    stage serial port or pty (default auto: first Arduino by USB "
        "VID:PID)\n"
        "  --camera SPEC       /dev/videoN, N, gst:PIPELINE or unix:PATH (libposeinfer)\n"
        "  --model FILE        ONNX model with spherepose metadata\n"
        "  --camera-file FILE  the camera's JSON file (docs/interfaces.md): expected sphere "
        "radius\n"
        "                      and lens distortion for sphere-crop-v2 models (undistorted first)\n"
        "  --plan FILE         poses, one 'x,y,z' per line in degrees (header line allowed)\n"
        "  --random N          N poses drawn uniformly in the ranges below\n"
        "  --range-x A,B       range of x for --random (default -30,30); also --range-y, "
        "--range-z\n"
        "  --seed S            seed of --random (default 1)\n"
        "  --home              run a homing cycle ($H) first\n"
        "  --settle MS         wait after the stage is Idle, before the grab (default 300)\n"
        "  --discard N         frames to grab and drop before the measured one (default 0;\n"
        "                      V4L2 cameras queue a few stale frames: try 4)\n"
        "  --feed DEG_MIN      move with G1 at this feed (default: G0, the stage's rapid rate)\n"
        "  --out DIR           output folder (default poserig-out; created)\n"
        "  --save-frames       also save each frame as OUT/frames/<x>_<y>_<z>.png\n"
        "  --retries N         after a reset or alarm mid-move, recover and retry a pose N times "
        "(default 1)\n"
        "  --allow-default-settings  run even when the controller restored its default settings\n"
        "                      (EEPROM CRC failure); without it such a stage is refused\n"
        "  --threads N         inference threads (default: libposeinfer's)\n"
        "  --no-refine         the network's angles, not refined (still judged, at them)\n"
        "  --camera-timeout MS connect/grab deadline of unix: cameras (default 5000)\n"
        "  --banner-timeout MS --timeout MS --poll MS --move-timeout MS   stage client deadlines\n"
        "                      (defaults 5000, 2000, 100, 120000)\n"
        "  -v, --verbose       trace the serial traffic on stderr\n"
        "  -h, --help          this text\n"
        "\n"
        "Exit status: 0 every pose measured (flagged ones too); 1 some poses failed or the stage\n"
        "stopped the run; 2 usage or set-up error; 128+signal when stopped by SIGINT/SIGTERM\n"
        "(partial results kept).\n",
        f);
}

static int parse_int(const char *s, int lo, int hi, int *v)
{
    char *end;
    long x;
    errno = 0;
    x = strtol(s, &end, 10);
    if (end == s || *end || errno || x < lo || x > hi) return -1;
    *v = (int)x;
    return 0;
}

/* mkdir -p */
static int make_dirs(const char *path, char *err)
{
    char tmp[4096], *p;
    snprintf(tmp, sizeof(tmp), "%s", path);
    for (p = tmp + 1;; p++) {
        if (*p == '/' || *p == '\0') {
            char c = *p;
            *p = '\0';
            if (mkdir(tmp, 0777) != 0 && errno != EEXIST) {
                rig_seterr(err, "mkdir(%.200s): %s", tmp, strerror(errno));
                return -1;
            }
            *p = c;
            if (c == '\0') break;
        }
    }
    return 0;
}

/* An angle as conventions.md's file names want it: up to 3 decimals, no
 * trailing zeros, no "-0". */
static char *fmt_angle(char *buf, size_t len, double v)
{
    char *dot, *e;
    if (v > -0.0005 && v < 0.0005) v = 0;
    snprintf(buf, len, "%.3f", v);
    dot = strchr(buf, '.');
    e = buf + strlen(buf) - 1;
    while (e > dot && *e == '0') *e-- = '\0';
    if (e == dot) *e = '\0';
    return buf;
}

/* Sleep ms unless a signal asks to stop. */
static void settle(int ms)
{
    double end = now_ms() + ms;
    while (!stop_signal) {
        double left = end - now_ms();
        struct timespec ts;
        if (left <= 0) break;
        if (left > 50) left = 50;
        ts.tv_sec = 0;
        ts.tv_nsec = (long)(left * 1e6);
        nanosleep(&ts, NULL);
    }
}

/* Stop the stage where it is: feed hold (decelerates, keeps the position),
 * wait for the hold to complete, then a soft reset to flush the planner. */
static void stop_stage(stage *s)
{
    char err[RIG_ERR_LEN];
    double deadline;
    if (s->fd < 0 || s->dead) return;
    s->o.cancel = NULL;
    if (stage_feed_hold(s, err) != 0) {
        fprintf(stderr, "poserig: %s\n", err);
        return;
    }
    deadline = now_ms() + 5000;
    while (now_ms() < deadline) {
        if (stage_status(s, NULL, err) != 0) break;
        if (strcmp(s->last.state, "Idle") == 0 ||
            (strcmp(s->last.state, "Hold") == 0 && s->last.substate == 0))
            break;
        settle(s->o.poll_ms);
    }
    if (stage_reset(s, err) != 0)
        fprintf(stderr, "poserig: %s\n", err);
    else
        fprintf(stderr, "poserig: stage held and reset (state %s)\n", s->last.state);
}

/* ---- the run's stages: parse, open, run, report ------------------------ */

/* The command line. */
typedef struct {
    const char *port, *camera, *model, *plan_file, *out;
    double range[3][2], feed;
    unsigned long long seed;
    int nrandom, home, settle_ms, discard, save_frames, retries, cam_timeout, allow_defaults;
    stage_opts so;
    pi_options piopt;
} rig_args;

/* What a run holds: the plan, its rows so far, and the open rig. */
typedef struct {
    rig_pose *poses;
    int npose;
    rig_row *rows;
    int nrows, failed, cam_fail_run;
    const char *stopped; /* why the run ended early, NULL if it did not */
    char plan_desc[256], started[32];
    double t_start;
    pi_ctx *ctx;
    pi_camera *cam;
    stage st;
} rig_run;

/* Parse the command line into a. Returns -1 to go on, else the exit status
 * (0 after --help, EXIT_USAGE for a bad argument). */
static int parse_args(int argc, char **argv, rig_args *a)
{
    static const struct option longopts[] = {
        {"port", required_argument, 0, 'p'},
        {"camera", required_argument, 0, 'c'},
        {"model", required_argument, 0, 'm'},
        {"plan", required_argument, 0, 'P'},
        {"random", required_argument, 0, 'n'},
        {"range-x", required_argument, 0, 'X'},
        {"range-y", required_argument, 0, 'Y'},
        {"range-z", required_argument, 0, 'Z'},
        {"seed", required_argument, 0, 'S'},
        {"home", no_argument, 0, 'H'},
        {"settle", required_argument, 0, 's'},
        {"discard", required_argument, 0, 'd'},
        {"feed", required_argument, 0, 'f'},
        {"out", required_argument, 0, 'o'},
        {"save-frames", no_argument, 0, 'F'},
        {"retries", required_argument, 0, 'r'},
        {"threads", required_argument, 0, 't'},
        {"camera-timeout", required_argument, 0, 'C'},
        {"banner-timeout", required_argument, 0, 'b'},
        {"timeout", required_argument, 0, 'T'},
        {"poll", required_argument, 0, 'l'},
        {"move-timeout", required_argument, 0, 'M'},
        {"allow-default-settings", no_argument, 0, 'D'},
        {"no-refine", no_argument, 0, 'R'},
        {"camera-file", required_argument, 0, 'K'},
        {"verbose", no_argument, 0, 'v'},
        {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    int c, longidx = 0, i;

    memset(a, 0, sizeof(*a));
    a->port = "auto";
    a->out = "poserig-out";
    for (i = 0; i < 3; i++) {
        a->range[i][0] = -30;
        a->range[i][1] = 30;
    }
    a->seed = 1;
    a->settle_ms = 300;
    a->retries = 1;
    a->cam_timeout = 5000;
    stage_opts_default(&a->so);
    pi_options_init(&a->piopt);
    while ((c = getopt_long(argc, argv, "vh", longopts, &longidx)) != -1) {
        double d;
        char *end;
        switch (c) {
        case 'p': a->port = optarg; break;
        case 'c': a->camera = optarg; break;
        case 'm': a->model = optarg; break;
        case 'P': a->plan_file = optarg; break;
        case 'n':
            if (parse_int(optarg, 1, RIG_PLAN_MAX, &a->nrandom) != 0) goto badarg;
            break;
        case 'X':
        case 'Y':
        case 'Z':
            if (rig_parse_range(optarg, &a->range[c - 'X'][0], &a->range[c - 'X'][1]) != 0)
                goto badarg;
            break;
        case 'S':
            errno = 0;
            a->seed = strtoull(optarg, &end, 10);
            if (end == optarg || *end || errno) goto badarg;
            break;
        case 'H': a->home = 1; break;
        case 's':
            if (parse_int(optarg, 0, 600000, &a->settle_ms) != 0) goto badarg;
            break;
        case 'd':
            if (parse_int(optarg, 0, 100, &a->discard) != 0) goto badarg;
            break;
        case 'f':
            d = strtod(optarg, &end);
            if (end == optarg || *end || !(d > 0)) goto badarg;
            a->feed = d;
            break;
        case 'o': a->out = optarg; break;
        case 'F': a->save_frames = 1; break;
        case 'r':
            if (parse_int(optarg, 0, 10, &a->retries) != 0) goto badarg;
            break;
        case 't':
            if (parse_int(optarg, 1, 64, &a->piopt.intra_threads) != 0) goto badarg;
            break;
        case 'C':
            if (parse_int(optarg, 1, 3600000, &a->cam_timeout) != 0) goto badarg;
            break;
        case 'b':
            if (parse_int(optarg, 1, 3600000, &a->so.banner_timeout_ms) != 0) goto badarg;
            break;
        case 'T':
            if (parse_int(optarg, 1, 3600000, &a->so.reply_timeout_ms) != 0) goto badarg;
            break;
        case 'l':
            if (parse_int(optarg, 1, 60000, &a->so.poll_ms) != 0) goto badarg;
            break;
        case 'M':
            if (parse_int(optarg, 1, 36000000, &a->so.move_timeout_ms) != 0) goto badarg;
            a->so.home_timeout_ms = a->so.move_timeout_ms;
            break;
        case 'D': a->allow_defaults = 1; break;
        case 'R': a->piopt.no_refine = 1; break;
        case 'K': a->piopt.camera_file = optarg; break;
        case 'v': a->so.log = stderr; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return EXIT_USAGE;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "poserig: unexpected argument '%s'\n", argv[optind]);
        return EXIT_USAGE;
    }
    if (!a->camera || !a->model || (!a->plan_file == !a->nrandom)) {
        fprintf(stderr,
                "poserig: needs --camera, --model, and one of --plan or --random (see --help)\n");
        return EXIT_USAGE;
    }
    return -1;
badarg:
    fprintf(stderr, "poserig: bad value '%s' for --%s (see --help)\n", optarg,
            longopts[longidx].name);
    return EXIT_USAGE;
}

/* Load the plan, make the output folders, then open the model, the camera
 * and the stage, in that order, and check that the stage may be measured
 * with. Returns 0, or -1 with err. */
static int open_rig(const rig_args *a, rig_run *r, char *err)
{
    char pierr[PI_ERR_LEN], path[4096];
    struct sigaction sa;

    /* Everything that can be checked without the rig, first. */
    if (a->plan_file) {
        if (rig_plan_load(a->plan_file, &r->poses, &r->npose, err) != 0) return -1;
        snprintf(r->plan_desc, sizeof(r->plan_desc), "file `%s`, %d poses", a->plan_file, r->npose);
    } else {
        if (rig_plan_random(a->nrandom, (const double(*)[2])a->range, a->seed, &r->poses, err) != 0)
            return -1;
        r->npose = a->nrandom;
        snprintf(r->plan_desc, sizeof(r->plan_desc),
                 "%d random poses, seed %llu, x in [%g, %g], y in [%g, %g], z in [%g, %g]",
                 a->nrandom, a->seed, a->range[0][0], a->range[0][1], a->range[1][0],
                 a->range[1][1], a->range[2][0], a->range[2][1]);
    }
    if (!(r->rows = calloc((size_t)r->npose, sizeof(*r->rows)))) {
        snprintf(err, RIG_ERR_LEN, "calloc: out of memory for %d poses", r->npose);
        return -1;
    }
    if (make_dirs(a->out, err) != 0) return -1;
    if (a->save_frames) {
        snprintf(path, sizeof(path), "%s/frames", a->out);
        if (make_dirs(path, err) != 0) return -1;
    }

    /* SIGINT/SIGTERM end the run between steps: no SA_RESTART, so a wait
     * on the port returns at once and sees the flag. */
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN); /* a camera socket that closes is an error, not a death */

    fprintf(stderr, "poserig: loading model %s\n", a->model);
    if (!(r->ctx = pi_open(a->model, &a->piopt, pierr))) {
        snprintf(err, RIG_ERR_LEN, "%s", pierr);
        return -1;
    }
    fprintf(stderr, "poserig: opening camera %s\n", a->camera);
    if (!(r->cam = pi_camera_open(a->camera, a->cam_timeout, pierr))) {
        snprintf(err, RIG_ERR_LEN, "%s", pierr);
        return -1;
    }
    fprintf(stderr, "poserig: opening stage %s\n", a->port);
    {
        stage_opts so = a->so;
        so.cancel = &stop_signal;
        if (stage_open(&r->st, a->port, &so, err) != 0) return -1;
    }
    fprintf(stderr, "poserig: stage %s on %s (%s), state %s\n",
            r->st.banner[0] ? r->st.banner : "(no banner)", r->st.path,
            r->st.via_termios ? "termios" : "libserialport", r->st.last.state);
    /* Defaults mean other steps per degree and limits than the rig's: every
     * pose would be measured against a wrong angle, quietly. */
    if (r->st.defaults_restored && !a->allow_defaults) {
        fprintf(stderr, "poserig: the stage says '%s'\n", r->st.restored_msg);
        rig_seterr(err,
                   "stage %.60s runs on the firmware's default settings, not the rig's: set them "
                   "again (stagectl settings, stagectl set) or give --allow-default-settings",
                   r->st.path);
        return -1;
    }
    if (r->st.defaults_restored)
        fprintf(stderr,
                "poserig: warning: the stage runs on default settings ('%s'); going on as told "
                "(--allow-default-settings)\n",
                r->st.restored_msg);
    if (a->home) {
        fprintf(stderr, "poserig: homing\n");
        if (stage_home(&r->st, err) != 0) return -1;
    } else if (strcmp(r->st.last.state, "Alarm") == 0) {
        snprintf(err, RIG_ERR_LEN,
                 "stage %.100s is in Alarm: give --home, or unlock it "
                 "(stagectl unlock) if its position is known",
                 r->st.path);
        return -1;
    }
    return 0;
}

enum { POSE_NEXT, POSE_STOP };

/* Move to pose i, settle, grab, estimate, and record the row; rewrite
 * poses.csv. POSE_STOP when the run must end here (r->stopped says why, or
 * a signal came). */
static int measure_pose(const rig_args *a, rig_run *r, int i)
{
    rig_row *row = &r->rows[r->nrows];
    pi_frame frame;
    pi_result res;
    char err[RIG_ERR_LEN], pierr[PI_ERR_LEN], path[4096];
    double t0 = now_ms(), t1;
    int attempt, k, moved = 0;

    memset(row, 0, sizeof(*row));
    row->index = i;
    memcpy(row->cmd, r->poses[i].xyz, sizeof(row->cmd));
    r->nrows++;

    /* Move, wait Idle; a reset or alarm mid-move is recovered and the
     * pose retried, since the stage then stands at an unknown place. */
    for (attempt = 0; attempt <= a->retries && !stop_signal; attempt++) {
        if (stage_move_wait(&r->st, row->cmd, a->feed, err) == 0) {
            moved = 1;
            break;
        }
        fprintf(stderr, "poserig: pose %d: %s\n", i, err);
        if (stop_signal || r->st.dead) break;
        if (!r->st.reset_seen && !r->st.last_alarm && strcmp(r->st.last.state, "Alarm") != 0) break;
        if (attempt == a->retries) break;
        fprintf(stderr, "poserig: recovering the stage (%s)\n",
                a->home ? "re-home if needed" : "unlock if safe");
        if (stage_recover(&r->st, a->home, err) != 0) {
            fprintf(stderr, "poserig: %s\n", err);
            break;
        }
    }
    row->move_ms = now_ms() - t0;
    memcpy(row->mpos, r->st.last.mpos, sizeof(row->mpos));
    memcpy(row->wpos, r->st.last.wpos, sizeof(row->wpos));
    /* A controller that restarted mid-run (a brown-out) may come back on
     * default settings: the stage then no longer turns the angles asked. */
    if (moved && r->st.defaults_restored && !a->allow_defaults) {
        fprintf(stderr,
                "poserig: pose %d: the stage restarted on its default settings ('%s'): stopping\n",
                i, r->st.restored_msg);
        snprintf(row->status, sizeof(row->status), "the stage restarted on its default settings");
        r->failed++;
        r->stopped = "the stage restarted on its default settings (EEPROM CRC check failed)";
        return POSE_STOP;
    }
    if (!moved) {
        snprintf(row->status, sizeof(row->status), "%.*s", (int)sizeof(row->status) - 1,
                 stop_signal ? "interrupted" : err);
        r->failed++;
        /* Any stage failure but a refused line (error:N) leaves the
         * stage in an unknown state: stop rather than measure nonsense. */
        if (stop_signal) return POSE_STOP;
        if (r->st.dead || !(r->st.last_error && strstr(err, "error:"))) {
            r->stopped = "the stage failed (see poses.csv)";
            return POSE_STOP;
        }
        goto row_done;
    }
    t1 = now_ms();
    settle(a->settle_ms);
    row->settle_ms = now_ms() - t1;
    if (stop_signal) {
        snprintf(row->status, sizeof(row->status), "interrupted");
        r->failed++;
        return POSE_STOP;
    }

    t1 = now_ms();
    for (k = 0; k <= a->discard; k++)
        if (pi_camera_grab(r->cam, &frame, pierr) != 0) break;
    row->grab_ms = now_ms() - t1;
    if (k <= a->discard) {
        snprintf(row->status, sizeof(row->status), "%.*s", (int)sizeof(row->status) - 1, pierr);
        r->failed++;
        fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
        if (++r->cam_fail_run >= 3) {
            r->stopped = "the camera failed three times in a row";
            return POSE_STOP;
        }
        goto row_done;
    }
    r->cam_fail_run = 0;
    row->decode_ms = frame.decode_ms;
    if (a->save_frames) {
        char x[24], y[24], z[24];
        snprintf(row->frame, sizeof(row->frame), "frames/%s_%s_%s.png",
                 fmt_angle(x, sizeof(x), row->cmd[0]), fmt_angle(y, sizeof(y), row->cmd[1]),
                 fmt_angle(z, sizeof(z), row->cmd[2]));
        snprintf(path, sizeof(path), "%s/%s", a->out, row->frame);
        if (pi_frame_save(&frame, path, pierr) != 0) {
            fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
            row->frame[0] = '\0';
        }
    }
    if (pi_infer_frame(r->ctx, &frame, &res, pierr) != 0) {
        snprintf(row->status, sizeof(row->status), "%.*s", (int)sizeof(row->status) - 1, pierr);
        r->failed++;
        fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
        goto row_done;
    }
    row->est[0] = res.x;
    row->est[1] = res.y;
    row->est[2] = res.z;
    row->preprocess_ms = res.preprocess_ms;
    row->locate_ms = res.locate_ms;
    row->infer_ms = res.infer_ms;
    if (res.has_confidence) {
        row->has_conf = 1;
        row->confident = res.confident;
        row->residual = res.residual;
        row->refine_ms = res.refine_ms;
        snprintf(row->note, sizeof(row->note), "%s", res.confident ? "" : res.note);
    }
    /* the circle poseinfer prints (checked against the refined radius,
     * docs/refine.md), in the CSV's OpenCV pixel centres */
    row->cx = res.circle[0] - 0.5;
    row->cy = res.circle[1] - 0.5;
    row->r = res.circle[2];
    rig_pose_errors(row->est, row->cmd, row->err);
    row->geo = rig_geodesic_deg(row->est, row->cmd);
    row->ok = 1;
    snprintf(row->status, sizeof(row->status), "ok");
    fprintf(stderr,
            "poserig: pose %d/%d cmd (%.3f, %.3f, %.3f) est (%.3f, %.3f, %.3f) "
            "err (%.3f, %.3f, %.3f)%s%s\n",
            i + 1, r->npose, row->cmd[0], row->cmd[1], row->cmd[2], row->est[0], row->est[1],
            row->est[2], row->err[0], row->err[1], row->err[2],
            rig_row_flagged(row) ? " flagged: " : "", rig_row_flagged(row) ? row->note : "");
row_done:
    row->pose_ms = now_ms() - t0;
    /* Rewritten whole after every pose: a run stopped in any way keeps
     * every pose measured so far in a complete file. */
    snprintf(path, sizeof(path), "%s/poses.csv", a->out);
    if (rig_write_csv(path, r->rows, r->nrows, err) != 0) {
        r->stopped = "could not write poses.csv";
        fprintf(stderr, "poserig: %s\n", err);
        return POSE_STOP;
    }
    return POSE_NEXT;
}

/* Measure every pose of the plan until the end, a stop, or a signal; on a
 * stop or a signal, hold and reset the stage. */
static void run_plan(const rig_args *a, rig_run *r)
{
    int i;
    time_t now = time(NULL);
    strftime(r->started, sizeof(r->started), "%Y-%m-%dT%H:%M:%SZ", gmtime(&now));
    r->t_start = now_ms();
    for (i = 0; i < r->npose && !stop_signal; i++)
        if (measure_pose(a, r, i) == POSE_STOP) break;
    if (stop_signal) {
        r->stopped = stop_signal == SIGINT ? "interrupted (SIGINT)" : "terminated (SIGTERM)";
        fprintf(stderr, "poserig: %s: stopping the stage, keeping %d pose(s)\n", r->stopped,
                r->nrows);
    }
    if (stop_signal || r->stopped) stop_stage(&r->st);
}

/* Write poses.csv, summary.md and boxplot.svg and print the Table 3
 * summary. Returns the exit status of the run. */
static int report(const rig_args *a, rig_run *r)
{
    rig_results sum;
    rig_run_info info;
    char err[RIG_ERR_LEN], path[4096];
    int rc = 0;

    memset(&info, 0, sizeof(info));
    info.port = r->st.path;
    info.camera = a->camera;
    info.model = a->model;
    info.plan = r->plan_desc;
    info.planned = r->npose;
    info.done = r->nrows - r->failed;
    info.failed = r->failed;
    info.stopped = r->stopped;
    info.elapsed_s = (now_ms() - r->t_start) / 1000.0;
    info.settle_ms = a->settle_ms;
    info.confidence = r->ctx ? pi_metadata(r->ctx, "spherepose.confidence") : NULL;
    info.no_refine = a->piopt.no_refine;
    snprintf(info.started, sizeof(info.started), "%s", r->started);
    snprintf(path, sizeof(path), "%s/poses.csv", a->out);
    if (rig_write_csv(path, r->rows, r->nrows, err) != 0 ||
        rig_summarise_rows(r->rows, r->nrows, &sum, err) != 0) {
        fprintf(stderr, "poserig: %s\n", err);
        rc = EXIT_SOME_FAILED;
    } else {
        rig_print_summary(stdout, &info, &sum, r->rows, r->nrows);
        snprintf(path, sizeof(path), "%s/summary.md", a->out);
        if (rig_write_summary_md(path, &info, &sum, r->rows, r->nrows, err) != 0) {
            fprintf(stderr, "poserig: %s\n", err);
            rc = EXIT_SOME_FAILED;
        }
        snprintf(path, sizeof(path), "%s/boxplot.svg", a->out);
        if (rig_write_boxplot_svg(path, &sum, r->rows, r->nrows, err) != 0) {
            fprintf(stderr, "poserig: %s\n", err);
            rc = EXIT_SOME_FAILED;
        }
        fflush(stdout);
        fprintf(stderr, "poserig: results in %s/ (poses.csv, summary.md, boxplot.svg%s)\n", a->out,
                a->save_frames ? ", frames/" : "");
    }
    if (r->failed || r->stopped || r->nrows < r->npose) rc = EXIT_SOME_FAILED;
    if (stop_signal) rc = 128 + stop_signal;
    return rc;
}

/* Close what open_rig opened (any part of it). */
static void close_rig(rig_run *r)
{
    stage_close(&r->st);
    pi_camera_close(r->cam);
    pi_close(r->ctx);
    free(r->rows);
    free(r->poses);
}

int main(int argc, char **argv)
{
    rig_args a;
    rig_run r;
    char err[RIG_ERR_LEN];
    int rc;

    if ((rc = parse_args(argc, argv, &a)) >= 0) return rc;
    memset(&r, 0, sizeof(r));
    r.st.fd = -1;
    if (open_rig(&a, &r, err) != 0) {
        fprintf(stderr, "poserig: %s\n", err);
        rc = stop_signal ? 128 + stop_signal : EXIT_USAGE;
    } else {
        run_plan(&a, &r);
        rc = report(&a, &r);
    }
    close_rig(&r);
    return rc;
}
