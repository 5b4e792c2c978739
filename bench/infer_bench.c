/* infer_bench.c -- the C side of bench/infer_bench.py: per-frame times (ms)
 * of (a) bare OrtRun on a ready tensor, (b) reading + decoding the file,
 * (c) the full libposeinfer path (pi_infer_file) with its split.
 *
 *   infer_bench MODEL.onnx ROUNDS THREADS CLOCK IMAGE...
 *
 * CLOCK: wall (monotonic) or cpu (process CPU time).
 *
 * Prints one JSON object: {"ortrun": [...], "decode": [...], "full": [...],
 * "full_decode": [...], "full_preprocess": [...], "full_infer": [...],
 * "full_refine": [...], "full_locate": [...] (of full_preprocess, finding the
 * sphere alone; 0 for a sphere-crop-v1 model), "refused": [{"file": ...,
 * "error": ...}], "cpu_paths": pi_cpu_paths()}.
 *
 * A frame the preprocessing refuses (no sphere, two spheres, cut by the
 * frame edge: an error "preprocess: ...") is listed under "refused" once and
 * left out of every later round; the bench goes on with the others. Any
 * other error ends it. */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "poseinfer.h" /* the public API only, as any program outside host/ */

/* s as a JSON string (the library's messages are printable ASCII; others escaped) */
static void print_json_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            printf("\\%c", c);
        else if (c < 0x20 || c > 0x7e)
            printf("\\u%04x", c);
        else
            putchar(c);
    }
    putchar('"');
}

static void print_array(const char *name, const double *v, size_t n, int last)
{
    printf("\"%s\": [", name);
    for (size_t i = 0; i < n; i++) printf("%s%.4f", i ? ", " : "", v[i]);
    printf("]%s", last ? "" : ", ");
}

int main(int argc, char **argv)
{
    char err[PI_ERR_LEN];
    pi_options o;
    pi_ctx *ctx = NULL;
    int rounds, nimg, rc = 1;
    char *refused = NULL;          /* per image: the preprocessing refused it */
    char(*why)[PI_ERR_LEN] = NULL; /* its error */
    double *t_run = NULL, *t_dec = NULL, *t_full = NULL, *t_fd = NULL, *t_fp = NULL, *t_fi = NULL,
           *t_fr = NULL, *t_fl = NULL;

    const char *camera_file = NULL;
    if (argc > 2 && strcmp(argv[1], "--camera-file") == 0) { /* a sphere-crop-v2 model's camera */
        camera_file = argv[2];
        argv += 2;
        argc -= 2;
    }
    if (argc < 6) {
        fprintf(stderr,
                "usage: infer_bench [--camera-file FILE] MODEL ROUNDS THREADS wall|cpu IMAGE...\n");
        return 2;
    }
    rounds = atoi(argv[2]);
    nimg = argc - 5;
    pi_use_cpu_clock(strcmp(argv[4], "cpu") == 0);
    size_t n = (size_t)rounds * nimg;
    pi_options_init(&o);
    o.intra_threads = atoi(argv[3]);
    o.camera_file = camera_file;
    ctx = pi_open(argv[1], &o, err);
    if (!ctx) {
        fprintf(stderr, "infer_bench: %s\n", err);
        return 2;
    }
    t_run = calloc(n, sizeof(double));
    t_dec = calloc(n, sizeof(double));
    t_full = calloc(n, sizeof(double));
    t_fd = calloc(n, sizeof(double));
    t_fp = calloc(n, sizeof(double));
    t_fi = calloc(n, sizeof(double));
    t_fr = calloc(n, sizeof(double));
    t_fl = calloc(n, sizeof(double));
    refused = calloc((size_t)nimg, 1);
    why = calloc((size_t)nimg, sizeof *why);
    if (!t_run || !t_dec || !t_full || !t_fd || !t_fp || !t_fi || !t_fr || !t_fl || !refused ||
        !why)
        goto fail;

    /* interleaved, so that a noisy neighbour hits all three alike; m frames timed */
    size_t m = 0;
    for (size_t i = 0; i < n; i++) {
        size_t img = i % (size_t)nimg, k = m;
        const char *path = argv[5 + img];
        pi_frame f;
        pi_result r;
        if (refused[img]) continue;
        double t0 = pi_now_ms();
        if (pi_load_file(ctx, path, &f, err) < 0) goto fail_err;
        t_dec[k] = pi_now_ms() - t0;
        if (pi_infer_file(ctx, path, &r, err) < 0) {
            if (strncmp(err, "preprocess: ", 12) != 0) goto fail_err;
            refused[img] = 1; /* a frame the localisation refuses: noted, not timed */
            snprintf(why[img], PI_ERR_LEN, "%s", err);
            continue;
        }
        m++;
        t_full[k] = r.total_ms;
        t_fd[k] = r.decode_ms;
        t_fp[k] = r.preprocess_ms;
        t_fi[k] = r.infer_ms;
        t_fr[k] = r.refine_ms;
        t_fl[k] = r.locate_ms;
        t0 = pi_now_ms();
        if (pi_run_only(ctx, err) < 0) goto fail_err; /* the tensor is ready from the line above */
        t_run[k] = pi_now_ms() - t0;
    }
    printf("{");
    print_array("ortrun", t_run, m, 0);
    print_array("decode", t_dec, m, 0);
    print_array("full", t_full, m, 0);
    print_array("full_decode", t_fd, m, 0);
    print_array("full_preprocess", t_fp, m, 0);
    print_array("full_infer", t_fi, m, 0);
    print_array("full_refine", t_fr, m, 0);
    print_array("full_locate", t_fl, m, 0);
    printf("\"refused\": [");
    for (int i = 0, first = 1; i < nimg; i++) {
        if (!refused[i]) continue;
        printf("%s{\"file\": ", first ? "" : ", ");
        print_json_string(argv[5 + i]);
        printf(", \"error\": ");
        print_json_string(why[i]);
        printf("}");
        first = 0;
    }
    printf("], \"cpu_paths\": ");
    print_json_string(pi_cpu_paths()); /* the times hold for these loops only */
    printf("}\n");
    rc = 0;
    goto fail;
fail_err:
    fprintf(stderr, "infer_bench: %s\n", err);
fail:
    free(t_run);
    free(t_dec);
    free(t_full);
    free(t_fd);
    free(t_fp);
    free(t_fi);
    free(t_fr);
    free(t_fl);
    free(refused);
    free(why);
    pi_close(ctx);
    return rc;
}
