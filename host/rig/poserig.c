/* poserig -- the paper's section 4 experiment on a real or simulated rig.
 *
 * For each pose of a plan: move the stage, wait until Idle and a settle
 * time, grab a frame, estimate the orientation with libposeinfer, and record
 * commanded pose, stage-reported position, estimate, errors and timings.
 * Writes OUT/poses.csv after every pose, then OUT/summary.md, OUT/boxplot.svg
 * and a Table 3 style summary on stdout. The stage port and the camera are
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
#define EXIT_USAGE 2

static volatile sig_atomic_t stop_signal;

static void on_signal(int sig) {
    stop_signal = sig;
}

static double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1000.0 + ts.tv_nsec / 1e6;
}

static void usage(FILE *f) {
    fputs("usage: poserig --camera SPEC --model MODEL.onnx (--plan FILE.csv | --random N) [options]\n"
          "\n"
          "Moves the stage through the plan; at each pose grabs a frame, estimates the\n"
          "sphere's orientation and records it; writes OUT/poses.csv, OUT/summary.md,\n"
          "OUT/boxplot.svg and prints a Table 3 style error summary (degrees).\n"
          "\n"
          "  --port PATH|auto    stage serial port or pty (default auto: first Arduino by USB VID:PID)\n"
          "  --camera SPEC       /dev/videoN, N, gst:PIPELINE or unix:PATH (libposeinfer)\n"
          "  --model FILE        ONNX model with spherepose metadata\n"
          "  --plan FILE         poses, one 'x,y,z' per line in degrees (header line allowed)\n"
          "  --random N          N poses drawn uniformly in the ranges below\n"
          "  --range-x A,B       range of x for --random (default -30,30); also --range-y, --range-z\n"
          "  --seed S            seed of --random (default 1)\n"
          "  --home              run a homing cycle ($H) first\n"
          "  --settle MS         wait after the stage is Idle, before the grab (default 300)\n"
          "  --discard N         frames to grab and drop before the measured one (default 0;\n"
          "                      V4L2 cameras queue a few stale frames: try 4)\n"
          "  --feed DEG_MIN      move with G1 at this feed (default: G0, the stage's rapid rate)\n"
          "  --out DIR           output folder (default poserig-out; created)\n"
          "  --save-frames       also save each frame as OUT/frames/<x>_<y>_<z>.png\n"
          "  --retries N         after a reset or alarm mid-move, recover and retry a pose N times (default 1)\n"
          "  --allow-default-settings  run even when the controller restored its default settings\n"
          "                      (EEPROM CRC failure); without it such a stage is refused\n"
          "  --threads N         inference threads (default: libposeinfer's)\n"
          "  --camera-timeout MS connect/grab deadline of unix: cameras (default 5000)\n"
          "  --banner-timeout MS --timeout MS --poll MS --move-timeout MS   stage client deadlines\n"
          "                      (defaults 5000, 2000, 100, 120000)\n"
          "  -v, --verbose       trace the serial traffic on stderr\n"
          "  -h, --help          this text\n"
          "\n"
          "Exit status: 0 every pose measured; 1 some poses failed or the stage stopped the run;\n"
          "2 usage or set-up error; 128+signal when stopped by SIGINT/SIGTERM (partial results kept).\n",
          f);
}

static int parse_int(const char *s, int lo, int hi, int *v) {
    char *end;
    long x;
    errno = 0;
    x = strtol(s, &end, 10);
    if (end == s || *end || errno || x < lo || x > hi) return -1;
    *v = (int)x;
    return 0;
}

/* mkdir -p */
static int make_dirs(const char *path, char *err) {
    char tmp[4096], *p;
    snprintf(tmp, sizeof(tmp), "%s", path);
    for (p = tmp + 1; ; p++) {
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
static char *fmt_angle(char *buf, size_t len, double v) {
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
static void settle(int ms) {
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
static void stop_stage(stage *s) {
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
    if (stage_reset(s, err) != 0) fprintf(stderr, "poserig: %s\n", err);
    else fprintf(stderr, "poserig: stage held and reset (state %s)\n", s->last.state);
}

int main(int argc, char **argv) {
    static const struct option longopts[] = {
        {"port", required_argument, 0, 'p'},      {"camera", required_argument, 0, 'c'},
        {"model", required_argument, 0, 'm'},     {"plan", required_argument, 0, 'P'},
        {"random", required_argument, 0, 'n'},    {"range-x", required_argument, 0, 'X'},
        {"range-y", required_argument, 0, 'Y'},   {"range-z", required_argument, 0, 'Z'},
        {"seed", required_argument, 0, 'S'},      {"home", no_argument, 0, 'H'},
        {"settle", required_argument, 0, 's'},    {"discard", required_argument, 0, 'd'},
        {"feed", required_argument, 0, 'f'},      {"out", required_argument, 0, 'o'},
        {"save-frames", no_argument, 0, 'F'},     {"retries", required_argument, 0, 'r'},
        {"threads", required_argument, 0, 't'},   {"camera-timeout", required_argument, 0, 'C'},
        {"banner-timeout", required_argument, 0, 'b'}, {"timeout", required_argument, 0, 'T'},
        {"poll", required_argument, 0, 'l'},      {"move-timeout", required_argument, 0, 'M'},
        {"allow-default-settings", no_argument, 0, 'D'},
        {"verbose", no_argument, 0, 'v'},         {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    const char *port = "auto", *camera = NULL, *model = NULL, *plan_file = NULL, *out = "poserig-out";
    double range[3][2] = {{-30, 30}, {-30, 30}, {-30, 30}}, feed = 0, t_start;
    unsigned long long seed = 1;
    int nrandom = 0, home = 0, settle_ms = 300, discard = 0, save_frames = 0, retries = 1;
    int cam_timeout = 5000, c, i, npose = 0, nrows = 0, failed = 0, rc = EXIT_USAGE;
    int cam_fail_run = 0, longidx = 0, allow_defaults = 0;
    char err[RIG_ERR_LEN];
    char pierr[PI_ERR_LEN], path[4096], plan_desc[256], startbuf[32];
    const char *stopped = NULL;
    rig_pose *poses = NULL;
    rig_row *rows = NULL;
    pi_options piopt;
    pi_ctx *ctx = NULL;
    pi_camera *cam = NULL;
    stage_opts so;
    stage st;
    struct sigaction sa;

    memset(&st, 0, sizeof(st));
    st.fd = -1;
    stage_opts_default(&so);
    pi_options_init(&piopt);
    while ((c = getopt_long(argc, argv, "vh", longopts, &longidx)) != -1) {
        double d;
        char *end;
        switch (c) {
        case 'p': port = optarg; break;
        case 'c': camera = optarg; break;
        case 'm': model = optarg; break;
        case 'P': plan_file = optarg; break;
        case 'n': if (parse_int(optarg, 1, RIG_PLAN_MAX, &nrandom) != 0) goto badarg; break;
        case 'X': case 'Y': case 'Z':
            if (rig_parse_range(optarg, &range[c - 'X'][0], &range[c - 'X'][1]) != 0) goto badarg;
            break;
        case 'S':
            errno = 0;
            seed = strtoull(optarg, &end, 10);
            if (end == optarg || *end || errno) goto badarg;
            break;
        case 'H': home = 1; break;
        case 's': if (parse_int(optarg, 0, 600000, &settle_ms) != 0) goto badarg; break;
        case 'd': if (parse_int(optarg, 0, 100, &discard) != 0) goto badarg; break;
        case 'f':
            d = strtod(optarg, &end);
            if (end == optarg || *end || !(d > 0)) goto badarg;
            feed = d;
            break;
        case 'o': out = optarg; break;
        case 'F': save_frames = 1; break;
        case 'r': if (parse_int(optarg, 0, 10, &retries) != 0) goto badarg; break;
        case 't': if (parse_int(optarg, 1, 64, &piopt.intra_threads) != 0) goto badarg; break;
        case 'C': if (parse_int(optarg, 1, 3600000, &cam_timeout) != 0) goto badarg; break;
        case 'b': if (parse_int(optarg, 1, 3600000, &so.banner_timeout_ms) != 0) goto badarg; break;
        case 'T': if (parse_int(optarg, 1, 3600000, &so.reply_timeout_ms) != 0) goto badarg; break;
        case 'l': if (parse_int(optarg, 1, 60000, &so.poll_ms) != 0) goto badarg; break;
        case 'M':
            if (parse_int(optarg, 1, 36000000, &so.move_timeout_ms) != 0) goto badarg;
            so.home_timeout_ms = so.move_timeout_ms;
            break;
        case 'D': allow_defaults = 1; break;
        case 'v': so.log = stderr; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return EXIT_USAGE;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "poserig: unexpected argument '%s'\n", argv[optind]);
        return EXIT_USAGE;
    }
    if (!camera || !model || (!plan_file == !nrandom)) {
        fprintf(stderr, "poserig: needs --camera, --model, and one of --plan or --random (see --help)\n");
        return EXIT_USAGE;
    }

    /* Everything that can be checked without the rig, first. */
    if (plan_file) {
        if (rig_plan_load(plan_file, &poses, &npose, err) != 0) goto setup_fail;
        snprintf(plan_desc, sizeof(plan_desc), "file `%s`, %d poses", plan_file, npose);
    } else {
        if (rig_plan_random(nrandom, (const double (*)[2])range, seed, &poses, err) != 0) goto setup_fail;
        npose = nrandom;
        snprintf(plan_desc, sizeof(plan_desc),
                 "%d random poses, seed %llu, x in [%g, %g], y in [%g, %g], z in [%g, %g]", nrandom,
                 seed, range[0][0], range[0][1], range[1][0], range[1][1], range[2][0], range[2][1]);
    }
    if (!(rows = calloc((size_t)npose, sizeof(*rows)))) {
        snprintf(err, sizeof(err), "calloc: out of memory for %d poses", npose);
        goto setup_fail;
    }
    if (make_dirs(out, err) != 0) goto setup_fail;
    if (save_frames) {
        snprintf(path, sizeof(path), "%s/frames", out);
        if (make_dirs(path, err) != 0) goto setup_fail;
    }

    /* SIGINT/SIGTERM end the run between steps: no SA_RESTART, so a wait
     * on the port returns at once and sees the flag. */
    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);   /* a camera socket that closes is an error, not a death */
    so.cancel = &stop_signal;

    fprintf(stderr, "poserig: loading model %s\n", model);
    if (!(ctx = pi_open(model, &piopt, pierr))) {
        snprintf(err, sizeof(err), "%s", pierr);
        goto setup_fail;
    }
    fprintf(stderr, "poserig: opening camera %s\n", camera);
    if (!(cam = pi_camera_open(camera, cam_timeout, pierr))) {
        snprintf(err, sizeof(err), "%s", pierr);
        goto setup_fail;
    }
    fprintf(stderr, "poserig: opening stage %s\n", port);
    if (stage_open(&st, port, &so, err) != 0) goto setup_fail;
    fprintf(stderr, "poserig: stage %s on %s (%s), state %s\n", st.banner[0] ? st.banner : "(no banner)",
            st.path, st.via_termios ? "termios" : "libserialport", st.last.state);
    /* Defaults mean other steps per degree and limits than the rig's: every
     * pose would be measured against a wrong angle, quietly. */
    if (st.defaults_restored && !allow_defaults) {
        fprintf(stderr, "poserig: the stage says '%s'\n", st.restored_msg);
        rig_seterr(err, "stage %.60s runs on the firmware's default settings, not the rig's: set them "
                   "again (stagectl settings, stagectl set) or give --allow-default-settings", st.path);
        goto setup_fail;
    }
    if (st.defaults_restored)
        fprintf(stderr, "poserig: warning: the stage runs on default settings ('%s'); going on as told "
                        "(--allow-default-settings)\n", st.restored_msg);
    if (home) {
        fprintf(stderr, "poserig: homing\n");
        if (stage_home(&st, err) != 0) goto setup_fail;
    } else if (strcmp(st.last.state, "Alarm") == 0) {
        snprintf(err, sizeof(err), "stage %.100s is in Alarm: give --home, or unlock it "
                 "(stagectl unlock) if its position is known", st.path);
        goto setup_fail;
    }

    {
        time_t now = time(NULL);
        strftime(startbuf, sizeof(startbuf), "%Y-%m-%dT%H:%M:%SZ", gmtime(&now));
    }
    t_start = now_ms();
    rc = 0;
    for (i = 0; i < npose && !stop_signal; i++) {
        rig_row *r = &rows[nrows];
        pi_frame frame;
        pi_result res;
        double t0 = now_ms(), t1;
        int attempt, k, moved = 0;

        memset(r, 0, sizeof(*r));
        r->index = i;
        memcpy(r->cmd, poses[i].xyz, sizeof(r->cmd));
        nrows++;

        /* Move, wait Idle; a reset or alarm mid-move is recovered and the
         * pose retried, since the stage then stands at an unknown place. */
        for (attempt = 0; attempt <= retries && !stop_signal; attempt++) {
            if (stage_move_wait(&st, r->cmd, feed, err) == 0) {
                moved = 1;
                break;
            }
            fprintf(stderr, "poserig: pose %d: %s\n", i, err);
            if (stop_signal || st.dead) break;
            if (!st.reset_seen && !st.last_alarm && strcmp(st.last.state, "Alarm") != 0) break;
            if (attempt == retries) break;
            fprintf(stderr, "poserig: recovering the stage (%s)\n", home ? "re-home if needed" : "unlock if safe");
            if (stage_recover(&st, home, err) != 0) {
                fprintf(stderr, "poserig: %s\n", err);
                break;
            }
        }
        r->move_ms = now_ms() - t0;
        memcpy(r->mpos, st.last.mpos, sizeof(r->mpos));
        memcpy(r->wpos, st.last.wpos, sizeof(r->wpos));
        if (!moved) {
            snprintf(r->status, sizeof(r->status), "%.*s", (int)sizeof(r->status) - 1, stop_signal ? "interrupted" : err);
            failed++;
            /* Any stage failure but a refused line (error:N) leaves the
             * stage in an unknown state: stop rather than measure nonsense. */
            if (stop_signal) break;
            if (st.dead || !(st.last_error && strstr(err, "error:"))) {
                stopped = "the stage failed (see poses.csv)";
                break;
            }
            goto row_done;
        }
        t1 = now_ms();
        settle(settle_ms);
        r->settle_ms = now_ms() - t1;
        if (stop_signal) {
            snprintf(r->status, sizeof(r->status), "interrupted");
            failed++;
            break;
        }

        t1 = now_ms();
        for (k = 0; k <= discard; k++)
            if (pi_camera_grab(cam, &frame, pierr) != 0) break;
        r->grab_ms = now_ms() - t1;
        if (k <= discard) {
            snprintf(r->status, sizeof(r->status), "%.*s", (int)sizeof(r->status) - 1, pierr);
            failed++;
            fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
            if (++cam_fail_run >= 3) {
                stopped = "the camera failed three times in a row";
                break;
            }
            goto row_done;
        }
        cam_fail_run = 0;
        r->decode_ms = frame.decode_ms;
        if (save_frames) {
            char a[24], b[24], cc[24];
            snprintf(r->frame, sizeof(r->frame), "frames/%s_%s_%s.png", fmt_angle(a, sizeof(a), r->cmd[0]),
                     fmt_angle(b, sizeof(b), r->cmd[1]), fmt_angle(cc, sizeof(cc), r->cmd[2]));
            snprintf(path, sizeof(path), "%s/%s", out, r->frame);
            if (pi_frame_save(&frame, path, pierr) != 0) {
                fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
                r->frame[0] = '\0';
            }
        }
        if (pi_infer_frame(ctx, &frame, &res, pierr) != 0) {
            snprintf(r->status, sizeof(r->status), "%.*s", (int)sizeof(r->status) - 1, pierr);
            failed++;
            fprintf(stderr, "poserig: pose %d: %s\n", i, pierr);
            goto row_done;
        }
        r->est[0] = res.x;
        r->est[1] = res.y;
        r->est[2] = res.z;
        r->preprocess_ms = res.preprocess_ms;
        r->infer_ms = res.infer_ms;
        r->cx = res.cx;
        r->cy = res.cy;
        r->r = res.r;
        rig_pose_errors(r->est, r->cmd, r->err);
        r->geo = rig_geodesic_deg(r->est, r->cmd);
        r->ok = 1;
        snprintf(r->status, sizeof(r->status), "ok");
        fprintf(stderr, "poserig: pose %d/%d cmd (%.3f, %.3f, %.3f) est (%.3f, %.3f, %.3f) "
                        "err (%.3f, %.3f, %.3f)\n", i + 1, npose, r->cmd[0], r->cmd[1], r->cmd[2],
                r->est[0], r->est[1], r->est[2], r->err[0], r->err[1], r->err[2]);
row_done:
        r->pose_ms = now_ms() - t0;
        /* Rewritten whole after every pose: a run stopped in any way keeps
         * every pose measured so far in a complete file. */
        snprintf(path, sizeof(path), "%s/poses.csv", out);
        if (rig_write_csv(path, rows, nrows, err) != 0) {
            stopped = "could not write poses.csv";
            fprintf(stderr, "poserig: %s\n", err);
            break;
        }
    }

    if (stop_signal) {
        stopped = stop_signal == SIGINT ? "interrupted (SIGINT)" : "terminated (SIGTERM)";
        fprintf(stderr, "poserig: %s: stopping the stage, keeping %d pose(s)\n", stopped, nrows);
    }
    if (stop_signal || stopped) stop_stage(&st);

    {
        rig_summary sum;
        rig_run_info info;
        memset(&info, 0, sizeof(info));
        info.port = st.path;
        info.camera = camera;
        info.model = model;
        info.plan = plan_desc;
        info.planned = npose;
        info.done = nrows - failed;
        info.failed = failed;
        info.stopped = stopped;
        info.elapsed_s = (now_ms() - t_start) / 1000.0;
        info.settle_ms = settle_ms;
        snprintf(info.started, sizeof(info.started), "%s", startbuf);
        snprintf(path, sizeof(path), "%s/poses.csv", out);
        if (rig_write_csv(path, rows, nrows, err) != 0 ||
            rig_summarise_rows(rows, nrows, &sum, err) != 0) {
            fprintf(stderr, "poserig: %s\n", err);
            rc = EXIT_SOME_FAILED;
        } else {
            rig_print_summary(stdout, &info, &sum);
            snprintf(path, sizeof(path), "%s/summary.md", out);
            if (rig_write_summary_md(path, &info, &sum, rows, nrows, err) != 0) {
                fprintf(stderr, "poserig: %s\n", err);
                rc = EXIT_SOME_FAILED;
            }
            snprintf(path, sizeof(path), "%s/boxplot.svg", out);
            if (rig_write_boxplot_svg(path, &sum, rows, nrows, err) != 0) {
                fprintf(stderr, "poserig: %s\n", err);
                rc = EXIT_SOME_FAILED;
            }
            fflush(stdout);
            fprintf(stderr, "poserig: results in %s/ (poses.csv, summary.md, boxplot.svg%s)\n", out,
                    save_frames ? ", frames/" : "");
        }
    }
    if (failed || stopped || nrows < npose) rc = EXIT_SOME_FAILED;
    if (stop_signal) rc = 128 + stop_signal;
    goto out;

setup_fail:
    fprintf(stderr, "poserig: %s\n", err);
    rc = stop_signal ? 128 + stop_signal : EXIT_USAGE;
out:
    stage_close(&st);
    pi_camera_close(cam);
    pi_close(ctx);
    free(rows);
    free(poses);
    return rc;
badarg:
    fprintf(stderr, "poserig: bad value '%s' for --%s (see --help)\n", optarg, longopts[longidx].name);
    return EXIT_USAGE;
}
