/* main.c -- poseinfer: images -> JSON lines; or a daemon (server, continuous
 * capture). Usage in usage() and docs/poseinfer.md. */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <unistd.h>

#include "access.h"
#include "config.h"
#include "internal.h"
#include "json.h"
#include "poseinfer.h"
#include "server.h"

#define EXIT_SOME_FAILED 1
#define EXIT_USAGE       2

static void usage(FILE *f)
{
    fputs(
        "usage: poseinfer --model MODEL.onnx [options] IMAGE|DIR ...\n"
        "       poseinfer --model MODEL.onnx --serve unix:PATH|tcp:127.0.0.1:PORT [--camera SPEC]\n"
        "       poseinfer --model MODEL.onnx --camera SPEC --continuous [--count N]\n"
        "\n"
        "Measure the orientation of the sphere in each image: one JSON line per\n"
        "image on stdout, {\"file\", \"x\", \"y\", \"z\" (degrees), \"ms\"} or {\"file\", "
        "\"error\"}.\n"
        "A DIR stands for its image files, sorted. Exit 0: all images gave a pose;\n"
        "1: some failed; 2: usage or model error.\n"
        "\n"
        "options (config-file key in brackets; flags override the file):\n"
        "  -m, --model FILE       ONNX model with spherepose metadata [model]\n"
        "  -c, --config FILE      read key = value settings from FILE\n"
        "  -s, --serve SPEC       serve the line protocol on unix:PATH or tcp:HOST:PORT [serve]\n"
        "      --camera SPEC      /dev/videoN, N, gst:PIPELINE or unix:PATH [camera]\n"
        "      --camera-file FILE the camera's JSON file (sphere-crop-v2 models): its expected "
        "sphere\n"
        "                         radius, and its lens distortion undone first [camera_file]\n"
        "      --continuous       capture and print one JSON line per frame [continuous]\n"
        "      --count N          stop after N frames in --continuous (default 0: run on) [count]\n"
        "      --interval-ms N    pause between continuous frames (default 0) [interval_ms]\n"
        "      --save-frames DIR  in --continuous, write each frame as DIR/frame_NNNNNN.png (the\n"
        "                         line's \"frame\" number; DIR made if its parent exists) "
        "[save_frames]\n"
        "      --threads N        ONNX Runtime intra-op threads (default 1) [threads]\n"
        "      --warmup N         warm-up runs at model load (default 1) [warmup]\n"
        "      --max-pixels N     refuse larger images (default 67108864) [max_pixels]\n"
        "      --timeout-ms N     frame-server timeout (default 5000) [timeout_ms]\n"
        "      --timings          add decode_ms, preprocess_ms (locate_ms of it), infer_ms,\n"
        "                         refine_ms, net, cx, cy, r [timings]\n"
        "      --no-refine        the network's angles, not refined against the model's texture\n"
        "                         (the residual and confidence still at them) [refine = no]\n"
        "      --max-file-bytes N refuse larger image files and frames (default 67108864) "
        "[max_file_bytes]\n"
        "      --workers N        daemon threads that infer frames (default 2) [workers]\n"
        "      --max-clients N    daemon connections at once; the next gets an error (default 64) "
        "[max_clients]\n"
        "      --idle-timeout-ms N  close a daemon client with no request for N ms (default "
        "60000)\n"
        "                         [idle_timeout_ms]\n"
        "      --allow-dir DIR    the daemon's `infer PATH` may read files beneath DIR; repeat "
        "for\n"
        "                         more (default none: frames come from the camera or the socket) "
        "[allow_dir]\n"
        "      --dump-tensor OUT  write the network input of the one IMAGE as raw float32 [3,S,S]\n"
        "  -h, --help             this help\n"
        "\n"
        "Signals: SIGTERM/SIGINT stop, SIGHUP reloads the model. Logs go to stderr.\n"
        "Protocol (one command per line, one JSON line back): ping, infer PATH, frame N,\n"
        "grab, stats, reload, auth TOKEN, quit. Config-file keys for the daemon as a\n"
        "shared service: socket_mode (0660), socket_group, tcp_remote, token_file\n"
        "(docs/poseinfer.md).\n",
        f);
}

static const struct option long_opts[] = {
    {"model", required_argument, 0, 'm'},
    {"config", required_argument, 0, 'c'},
    {"serve", required_argument, 0, 's'},
    {"camera", required_argument, 0, 1},
    {"camera-file", required_argument, 0, 16},
    {"save-frames", required_argument, 0, 17},
    {"continuous", no_argument, 0, 2},
    {"count", required_argument, 0, 3},
    {"interval-ms", required_argument, 0, 4},
    {"threads", required_argument, 0, 5},
    {"warmup", required_argument, 0, 6},
    {"max-pixels", required_argument, 0, 7},
    {"timeout-ms", required_argument, 0, 8},
    {"timings", no_argument, 0, 9},
    {"dump-tensor", required_argument, 0, 10},
    {"allow-dir", required_argument, 0, 11},
    {"max-file-bytes", required_argument, 0, 12},
    {"workers", required_argument, 0, 13},
    {"max-clients", required_argument, 0, 14},
    {"idle-timeout-ms", required_argument, 0, 15},
    {"no-refine", no_argument, 0, 40},
    {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0},
};

static int is_image_name(const char *name)
{
    static const char *ext[] = {".png",  ".jpg", ".jpeg", ".bmp", ".tif", ".tiff",
                                ".webp", ".pbm", ".pgm",  ".ppm", ".pnm", NULL};
    const char *dot = strrchr(name, '.');
    if (!dot || name[0] == '.') return 0;
    for (int i = 0; ext[i]; i++)
        if (strcasecmp(dot, ext[i]) == 0) return 1;
    return 0;
}

/* --save-frames' DIR, made if missing (one level, as mkdir: its parent must
 * exist), or -1 with err "DIR: reason". The frames' names must fit PATH_MAX. */
static int make_dir(const char *dir, char *err)
{
    struct stat st;
    if (strlen(dir) > PATH_MAX - 32) {
        pi_seterr(err, "%.64s...: the folder's name is too long", dir);
        return -1;
    }
    if (mkdir(dir, 0777) < 0 && errno != EEXIST) {
        pi_seterr(err, "%s: cannot make the folder: %s", dir, strerror(errno));
        return -1;
    }
    if (stat(dir, &st) < 0 || !S_ISDIR(st.st_mode)) {
        pi_seterr(err, "%s: not a folder", dir);
        return -1;
    }
    return 0;
}

static int cmp_str(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

static void print_line(sbuf *s)
{
    if (s->buf) {
        fputs(s->buf, stdout);
        fputc('\n', stdout);
    } else {
        fputs("{\"error\": \"out of memory\"}\n", stdout);
    }
    fflush(stdout);
    sb_reset(s);
}

/* Infer one file and print its line; 0 when it gave a pose. */
static int do_file(pi_ctx *ctx, const char *path, const pi_config *cfg, sbuf *s)
{
    char err[PI_ERR_LEN];
    pi_result r;
    int rc = pi_infer_file(ctx, path, &r, err);
    if (rc < 0)
        error_json(s, "file", path, err);
    else
        result_json(s, "file", path, &r, cfg->timings);
    print_line(s);
    return rc;
}

/* A directory: its image files, sorted by name. Returns failures. */
static int do_dir(pi_ctx *ctx, const char *dir, const pi_config *cfg, sbuf *s)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    char **names = NULL;
    size_t n = 0, cap = 0;
    int failed = 0, oom = 0;
    char err[PI_ERR_LEN];
    if (!d) {
        pi_seterr(err, "opendir(%s): %s", dir, strerror(errno));
        error_json(s, "file", dir, err);
        print_line(s);
        return 1;
    }
    while ((e = readdir(d))) {
        size_t len;
        char *p;
        if (!is_image_name(e->d_name)) continue;
        if (n == cap) {
            char **nn = realloc(names, (cap ? cap * 2 : 64) * sizeof *nn);
            if (!nn) {
                oom = 1;
                break;
            }
            names = nn;
            cap = cap ? cap * 2 : 64;
        }
        len = strlen(dir) + strlen(e->d_name) + 2;
        p = malloc(len);
        if (!p) {
            oom = 1;
            break;
        }
        snprintf(p, len, "%s%s%s", dir, dir[strlen(dir) - 1] == '/' ? "" : "/", e->d_name);
        names[n++] = p;
    }
    closedir(d);
    if (oom) {
        error_json(s, "file", dir, "out of memory listing the directory");
        print_line(s);
        failed = 1;
    } else if (n == 0) {
        error_json(s, "file", dir, "no image files in directory");
        print_line(s);
        failed = 1;
    }
    if (n > 1) qsort(names, n, sizeof *names, cmp_str);
    for (size_t i = 0; i < n; i++) {
        if (do_file(ctx, names[i], cfg, s) < 0) failed++;
        free(names[i]);
    }
    free(names);
    return failed;
}

static int dump_tensor(pi_ctx *ctx, const char *image, const pi_config *cfg, sbuf *s)
{
    char err[PI_ERR_LEN];
    pi_frame f;
    pi_result r;
    float *buf = NULL;
    FILE *out = NULL;
    size_t n = (size_t)3 * pi_input_size(ctx) * pi_input_size(ctx);
    int rc = -1;

    buf = malloc(n * sizeof(float));
    if (!buf) {
        pi_seterr(err, "dump-tensor: out of memory");
        goto fail;
    }
    if (pi_load_file(ctx, image, &f, err) < 0) goto fail;
    if (pi_preprocess_frame(ctx, &f, buf, n, &r, err) < 0) goto fail;
    out = fopen(cfg->dump_tensor, "wb");
    if (!out) {
        pi_seterr(err, "fopen(%s): %s", cfg->dump_tensor, strerror(errno));
        goto fail;
    }
    if (fwrite(buf, sizeof(float), n, out) != n || fclose(out) != 0) {
        out = NULL;
        pi_seterr(err, "write(%s): %s", cfg->dump_tensor, strerror(errno));
        goto fail;
    }
    out = NULL;
    if (pi_infer_frame(ctx, &f, &r, err) < 0) goto fail;
    result_json(s, "file", image, &r, 1);
    print_line(s);
    free(buf);
    return 0;
fail:
    if (out) fclose(out);
    free(buf);
    error_json(s, "file", image, err);
    print_line(s);
    return rc;
}

int main(int argc, char **argv)
{
    pi_config cfg;
    pi_options o;
    app a;
    sbuf s;
    char err[PI_ERR_LEN];
    int c, rc = EXIT_USAGE, lfd = -1, allow_flag = 0;
    access_policy acc;

    config_init(&cfg);
    memset(&a, 0, sizeof a);
    memset(&acc, 0, sizeof acc);
    sb_init(&s);

    /* Pass 1: only --config, so that the other flags override the file. */
    opterr = 0;
    while ((c = getopt_long(argc, argv, "m:c:s:h", long_opts, NULL)) != -1) {
        if (c == 'c' && config_load(&cfg, optarg, err) < 0) {
            fprintf(stderr, "poseinfer: %s\n", err);
            goto out;
        }
    }
    /* Pass 2: everything else. */
    opterr = 1;
    optind = 0;
    while ((c = getopt_long(argc, argv, "m:c:s:h", long_opts, NULL)) != -1) {
        const char *key = NULL, *val = optarg;
        switch (c) {
        case 'm': key = "model"; break;
        case 'c': continue;
        case 's': key = "serve"; break;
        case 1: key = "camera"; break;
        case 2:
            key = "continuous";
            val = "yes";
            break;
        case 3: key = "count"; break;
        case 4: key = "interval_ms"; break;
        case 5: key = "threads"; break;
        case 6: key = "warmup"; break;
        case 7: key = "max_pixels"; break;
        case 8: key = "timeout_ms"; break;
        case 9:
            key = "timings";
            val = "yes";
            break;
        case 10:
            free(cfg.dump_tensor);
            cfg.dump_tensor = strdup(optarg);
            continue;
        case 11:
            /* the flags' list replaces the file's */
            if (!allow_flag) config_clear_allow_dirs(&cfg);
            allow_flag = 1;
            key = "allow_dir";
            break;
        case 12: key = "max_file_bytes"; break;
        case 13: key = "workers"; break;
        case 14: key = "max_clients"; break;
        case 15: key = "idle_timeout_ms"; break;
        case 16: key = "camera_file"; break;
        case 17: key = "save_frames"; break;
        case 40:
            key = "refine";
            val = "no";
            break;
        case 'h':
            usage(stdout);
            rc = 0;
            goto out;
        default: usage(stderr); goto out;
        }
        if (config_set(&cfg, key, val, err) < 0) {
            fprintf(stderr, "poseinfer: --%s\n", err);
            goto out;
        }
    }
    if (!cfg.model) {
        fprintf(stderr, "poseinfer: no model (--model FILE.onnx or model = in --config)\n");
        usage(stderr);
        goto out;
    }
    if (cfg.continuous && !cfg.camera) {
        fprintf(stderr, "poseinfer: --continuous needs --camera SPEC\n");
        goto out;
    }
    if (cfg.continuous && cfg.serve) {
        fprintf(stderr, "poseinfer: --continuous and --serve exclude each other\n");
        goto out;
    }
    if (cfg.save_frames && !cfg.continuous) {
        fprintf(stderr,
                "poseinfer: --save-frames is for --continuous (poserig --save-frames keeps a "
                "run's frames)\n");
        goto out;
    }
    if (cfg.save_frames && make_dir(cfg.save_frames, err) < 0) {
        fprintf(stderr, "poseinfer: --save-frames %s\n", err);
        goto out;
    }
    if (!cfg.serve && !cfg.continuous && optind >= argc) {
        fprintf(stderr, "poseinfer: no images (IMAGE|DIR ...)\n");
        usage(stderr);
        goto out;
    }
    if (cfg.dump_tensor && argc - optind != 1) {
        fprintf(stderr, "poseinfer: --dump-tensor takes exactly one IMAGE\n");
        goto out;
    }

    pi_max_file_bytes = cfg.max_file_bytes;
    pi_options_init(&o);
    o.intra_threads = cfg.threads;
    o.warmup_runs = cfg.warmup;
    o.max_pixels = cfg.max_pixels;
    o.no_refine = !cfg.refine;
    o.camera_file = cfg.camera_file;
    a.cfg = &cfg;
    a.started_ms = pi_now_ms();
    a.ctx = pi_open(cfg.model, &o, err);
    if (!a.ctx) {
        fprintf(stderr, "poseinfer: %s\n", err);
        goto out;
    }

    if (cfg.serve || cfg.continuous) {
        if (signals_install(err) < 0) {
            fprintf(stderr, "poseinfer: %s\n", err);
            rc = 1;
            goto out;
        }
        if (cfg.camera) {
            a.cam = pi_camera_open(cfg.camera, cfg.timeout_ms, err);
            if (!a.cam) {
                fprintf(stderr, "poseinfer: %s\n", err);
                rc = EXIT_USAGE;
                goto out;
            }
        }
        if (cfg.continuous) {
            log_msg("continuous capture from %s with %s", cfg.camera, cfg.model);
            rc = continuous_run(&a, err) < 0 ? 1 : 0;
            goto out;
        }
        if (access_init(&acc, &cfg, err) < 0) {
            fprintf(stderr, "poseinfer: %s\n", err);
            rc = EXIT_USAGE;
            goto out;
        }
        a.acc = &acc;
        {
            listen_opts lo = {cfg.socket_mode, cfg.socket_group, cfg.tcp_remote, acc.token != NULL};
            lfd = server_listen(cfg.serve, &lo, err);
        }
        if (lfd < 0) {
            fprintf(stderr, "poseinfer: %s\n", err);
            rc = EXIT_USAGE;
            goto out;
        }
        if (strncmp(cfg.serve, "tcp:", 4) == 0) {
            /* Say the port actually bound (tcp:127.0.0.1:0 picks one). */
            struct sockaddr_storage ss;
            socklen_t sl = sizeof ss;
            if (getsockname(lfd, (struct sockaddr *)&ss, &sl) == 0 && ss.ss_family == AF_INET) {
                struct sockaddr_in *sin = (struct sockaddr_in *)&ss;
                char ip[32];
                inet_ntop(AF_INET, &sin->sin_addr, ip, sizeof ip);
                log_msg("listening on tcp:%s:%u (model %s)", ip, ntohs(sin->sin_port), cfg.model);
            }
        } else {
            log_msg("listening on %s (model %s)", cfg.serve, cfg.model);
        }
        rc = server_run(&a, lfd, cfg.serve, err) < 0 ? 1 : 0;
        if (rc) log_msg("%s", err);
        goto out;
    }

    if (cfg.dump_tensor) {
        rc = dump_tensor(a.ctx, argv[optind], &cfg, &s) < 0 ? EXIT_SOME_FAILED : 0;
        goto out;
    }

    {
        int failed = 0;
        for (int i = optind; i < argc; i++) {
            struct stat st;
            if (stat(argv[i], &st) == 0 && S_ISDIR(st.st_mode))
                failed += do_dir(a.ctx, argv[i], &cfg, &s);
            else if (do_file(a.ctx, argv[i], &cfg, &s) < 0)
                failed++;
        }
        rc = failed ? EXIT_SOME_FAILED : 0;
    }
out:
    if (lfd >= 0) close(lfd);
    pi_camera_close(a.cam);
    pi_close(a.ctx);
    access_free(&acc);
    sb_free(&s);
    config_free(&cfg);
    return rc;
}
