/* poseinfer.c -- libposeinfer: model loading and inference through the ONNX
 * Runtime C API, tuned for one frame at a time. */
#define _POSIX_C_SOURCE 200809L
#include "poseinfer.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <onnxruntime_c_api.h>

#include "internal.h"
#include "json.h"
#include "confidence.h"
#include "refine.h"
#include "shim.h"

#define META_PREPROCESS "spherepose.preprocess"

struct pi_ctx {
    const OrtApi *ort;
    OrtEnv *env;
    OrtSessionOptions *opts;
    OrtSession *sess;
    OrtMemoryInfo *mem;
    OrtValue *in_val;
    OrtValue *out_val[2];
    float *in_buf;  /* [3, S, S], wrapped by in_val */
    float euler[3]; /* wrapped by out_val[0] */
    float rot[9];   /* wrapped by out_val[1] */
    int has_rotmat;
    pp_params pp;
    long max_pixels;
    rf_texture *rf_tex; /* the model's texture (NULL: no refinement), shared by clones */
    rf_work *rf_w;      /* refinement's working memory, per context */
    rf_conf rf_conf;    /* confidence thresholds and the model's ranges */
    int rf_on;          /* refine (else only the residual at the network's pose) */
    double rf_focal;    /* camera focal length in pixels, 0 = from the circle */
    size_t nmeta;
    char **meta_keys, **meta_vals;
    shim_mat *mat;          /* decoded frame of the last pi_infer_file/memory */
    shim_mat *und;          /* the last frame undistorted (a camera with distortion) */
    double loc_cov[3];      /* the last localisation's centre covariance (pp_circle cov) */
    unsigned char *filebuf; /* reused read buffer */
    size_t filecap;
    size_t frame_bytes; /* size of the pixels held in mat */
    pi_ctx *parent;     /* a clone (pi_clone): the context that owns the session */
    int refs;           /* the owner: itself plus its clones (atomic) */
};

static clockid_t pi_clock = CLOCK_MONOTONIC;

static int setup_refine(pi_ctx *ctx, const char *model, const pi_options *opt, char *err);

void pi_use_cpu_clock(int on)
{
    pi_clock = on ? CLOCK_PROCESS_CPUTIME_ID : CLOCK_MONOTONIC;
}

double pi_now_ms(void)
{
    struct timespec ts;
    clock_gettime(pi_clock, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

/* Turn an OrtStatus into "call: message" (one line), and release it. */
static int ort_fail(const OrtApi *ort, OrtStatus *st, char *err, const char *call)
{
    char msg[PI_ERR_LEN];
    snprintf(msg, sizeof msg, "%s", ort->GetErrorMessage(st));
    for (char *c = msg; *c; c++)
        if (*c == '\n' || *c == '\r') *c = ' ';
    pi_seterr(err, "%s: %s", call, msg);
    ort->ReleaseStatus(st);
    return -1;
}

#define ORT_CHECK(expr, call)                   \
    do {                                        \
        OrtStatus *st_ = (expr);                \
        if (st_) {                              \
            ort_fail(ctx->ort, st_, err, call); \
            goto fail;                          \
        }                                       \
    } while (0)

void pi_options_init(pi_options *o)
{
    o->intra_threads = 0;
    o->warmup_runs = 1;
    o->max_pixels = PI_DEFAULT_MAX_PIXELS;
    o->no_refine = 0;
    o->focal_px = 0;
    o->camera_file = NULL;
}

/* The camera file (sphere-crop-v2 only): expected radius, undistortion. */
static int load_camera(pi_ctx *ctx, const char *model, const char *path, char *err)
{
    if (ctx->pp.version != 2) {
        pi_seterr(err,
                  "pi_open(%s): the model's preprocessing is sphere-crop-v1, which takes no camera "
                  "file (%s)",
                  model, path);
        return -1;
    }
    if (pp_camera_load(path, &ctx->pp.cam, err) < 0) return -1;
    return shim_camera_prepare(&ctx->pp, err);
}

/* ---- preprocessing parameters from the metadata JSON --------------------- */

/* A sphere-crop-v1 key the metadata lacks: refused, naming it (the
 * parameters' one source is training/preprocess.py, whose export writes
 * every key; the C side fills none). */
static int pp_missing(const char *key, char *err, const char *model)
{
    pi_seterr(
        err,
        "pi_open(%s): metadata %s: sphere-crop-v1 needs key \"%s\" (the model's export wrote no "
        "value for it)",
        model, META_PREPROCESS, key);
    return -1;
}

static int pp_number(const json_value *root, const char *key, double lo, double hi, double *out,
                     char *err, const char *model)
{
    const json_value *v = json_get(root, key);
    if (!v) return pp_missing(key, err, model);
    if (v->type != JSON_NUMBER || !(v->number >= lo && v->number <= hi)) {
        pi_seterr(err, "pi_open(%s): metadata %s: \"%s\" must be a number in [%g, %g]", model,
                  META_PREPROCESS, key, lo, hi);
        return -1;
    }
    *out = v->number;
    return 0;
}

static int pp_triple(const json_value *root, const char *key, float out[3], int positive, char *err,
                     const char *model)
{
    const json_value *v = json_get(root, key);
    if (!v) return pp_missing(key, err, model);
    if (v->type != JSON_ARRAY || v->count != 3) goto bad;
    for (int i = 0; i < 3; i++) {
        if (v->items[i].type != JSON_NUMBER) goto bad;
        if (positive && !(v->items[i].number > 0)) goto bad;
        out[i] = (float)v->items[i].number;
    }
    return 0;
bad:
    pi_seterr(err, "pi_open(%s): metadata %s: \"%s\" must be 3 numbers%s", model, META_PREPROCESS,
              key, positive ? " > 0" : "");
    return -1;
}

int pi_parse_preprocess(const char *text, pp_params *p, char *err, const char *model)
{
    json_value root;
    char jerr[128];
    double size;
    memset(p, 0, sizeof *p);
    p->version = 1;
    if (json_parse(text, &root, jerr, sizeof jerr) < 0) {
        pi_seterr(err, "pi_open(%s): metadata %s: %s", model, META_PREPROCESS, jerr);
        return -1;
    }
    if (root.type != JSON_OBJECT) {
        pi_seterr(err, "pi_open(%s): metadata %s: not a JSON object", model, META_PREPROCESS);
        goto fail;
    }
    const json_value *name = json_get(&root, "name");
    if (!name) {
        pi_seterr(err,
                  "pi_open(%s): metadata %s: needs key \"name\" (the preprocessing, "
                  "\"sphere-crop-v1\" or "
                  "\"sphere-crop-v2\")",
                  model, META_PREPROCESS);
        goto fail;
    }
    if (name->type == JSON_STRING && strcmp(name->string, "sphere-crop-v2") == 0) {
        int rc = pp_parse_v2(&root, p, err, model); /* pp_v2.c: every key, no defaults */
        json_free(&root);
        return rc;
    }
    if (name->type != JSON_STRING || strcmp(name->string, "sphere-crop-v1") != 0) {
        pi_seterr(err,
                  "pi_open(%s): metadata %s: unknown preprocessing %s; this runtime implements "
                  "\"sphere-crop-v1\" and \"sphere-crop-v2\"",
                  model, META_PREPROCESS,
                  name->type == JSON_STRING ? name->string : "(not a string)");
        goto fail;
    }
    if (pp_number(&root, "size", 8, 2048, &size, err, model) < 0) goto fail;
    if (size != floor(size)) {
        pi_seterr(err, "pi_open(%s): metadata %s: \"size\" must be an integer", model,
                  META_PREPROCESS);
        goto fail;
    }
    p->size = (int)size;
    if (pp_number(&root, "margin", 0.5, 10, &p->margin, err, model) < 0 ||
        pp_number(&root, "fg_threshold", 0, 255, &p->fg_threshold, err, model) < 0 ||
        pp_number(&root, "border_frac", 0, 0.5, &p->border_frac, err, model) < 0 ||
        pp_number(&root, "close_frac", 0, 0.5, &p->close_frac, err, model) < 0 ||
        pp_number(&root, "min_area_frac", 0, 1, &p->min_area_frac, err, model) < 0 ||
        pp_triple(&root, "mean", p->mean, 0, err, model) < 0 ||
        pp_triple(&root, "std", p->std, 1, err, model) < 0)
        goto fail;
    json_free(&root);
    return 0;
fail:
    json_free(&root);
    return -1;
}

/* ---- model contract -------------------------------------------------------- */

static void shape_str(const int64_t *d, size_t n, char *buf, size_t len)
{
    size_t o = 0;
    o += (size_t)snprintf(buf + o, len - o, "[");
    for (size_t i = 0; i < n && o < len; i++)
        o += (size_t)snprintf(buf + o, len - o, "%s%lld", i ? "," : "", (long long)d[i]);
    if (o < len) snprintf(buf + o, len - o, "]");
}

/* Element type and shape of a session input or output. */
static int io_shape(pi_ctx *ctx, int input, size_t idx, int64_t *dims, size_t *ndims,
                    ONNXTensorElementDataType *type, char *err)
{
    OrtTypeInfo *ti = NULL;
    const OrtTensorTypeAndShapeInfo *tsi = NULL;
    ONNXType ot;
    if (input)
        ORT_CHECK(ctx->ort->SessionGetInputTypeInfo(ctx->sess, idx, &ti),
                  "SessionGetInputTypeInfo");
    else
        ORT_CHECK(ctx->ort->SessionGetOutputTypeInfo(ctx->sess, idx, &ti),
                  "SessionGetOutputTypeInfo");
    ORT_CHECK(ctx->ort->GetOnnxTypeFromTypeInfo(ti, &ot), "GetOnnxTypeFromTypeInfo");
    if (ot != ONNX_TYPE_TENSOR) {
        pi_seterr(err, "model: %s %zu is not a tensor", input ? "input" : "output", idx);
        goto fail;
    }
    ORT_CHECK(ctx->ort->CastTypeInfoToTensorInfo(ti, &tsi), "CastTypeInfoToTensorInfo");
    ORT_CHECK(ctx->ort->GetTensorElementType(tsi, type), "GetTensorElementType");
    ORT_CHECK(ctx->ort->GetDimensionsCount(tsi, ndims), "GetDimensionsCount");
    if (*ndims > 8) {
        pi_seterr(err, "model: tensor of rank %zu", *ndims);
        goto fail;
    }
    ORT_CHECK(ctx->ort->GetDimensions(tsi, dims, *ndims), "GetDimensions");
    ctx->ort->ReleaseTypeInfo(ti);
    return 0;
fail:
    if (ti) ctx->ort->ReleaseTypeInfo(ti);
    return -1;
}

/* dims must equal want, where a model dimension < 0 (symbolic) matches
 * anything. */
static int shape_matches(const int64_t *dims, size_t n, const int64_t *want, size_t wn)
{
    if (n != wn) return 0;
    for (size_t i = 0; i < n; i++)
        if (dims[i] >= 0 && dims[i] != want[i]) return 0;
    return 1;
}

/* Check the ONNX model contract (docs/interfaces.md) and find rotmat. */
static int check_contract(pi_ctx *ctx, const char *model, char *err)
{
    OrtAllocator *alloc = NULL;
    size_t nin = 0, nout = 0, nd;
    int64_t dims[8];
    char shp[96];
    ONNXTensorElementDataType type;
    const int64_t S = ctx->pp.size;
    const int64_t want_in[4] = {1, 3, S, S}, want_e[2] = {1, 3}, want_r[3] = {1, 3, 3};
    int found_e = 0;

    ORT_CHECK(ctx->ort->GetAllocatorWithDefaultOptions(&alloc), "GetAllocatorWithDefaultOptions");
    ORT_CHECK(ctx->ort->SessionGetInputCount(ctx->sess, &nin), "SessionGetInputCount");
    ORT_CHECK(ctx->ort->SessionGetOutputCount(ctx->sess, &nout), "SessionGetOutputCount");
    if (nin != 1) {
        pi_seterr(err, "pi_open(%s): model has %zu inputs, expected 1 (\"image\")", model, nin);
        goto fail;
    }
    {
        char *name = NULL;
        int ok;
        ORT_CHECK(ctx->ort->SessionGetInputName(ctx->sess, 0, alloc, &name), "SessionGetInputName");
        ok = strcmp(name, "image") == 0;
        if (!ok)
            pi_seterr(err, "pi_open(%s): model input is \"%s\", expected \"image\"", model, name);
        alloc->Free(alloc, name);
        if (!ok) goto fail;
    }
    if (io_shape(ctx, 1, 0, dims, &nd, &type, err) < 0) goto fail;
    shape_str(dims, nd, shp, sizeof shp);
    if (type != ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT || !shape_matches(dims, nd, want_in, 4)) {
        pi_seterr(err,
                  "pi_open(%s): model input \"image\" is %s%s, expected float32 [N,3,%lld,%lld] "
                  "(size from %s)",
                  model, type != ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT ? "not float32, " : "", shp,
                  (long long)S, (long long)S, META_PREPROCESS);
        goto fail;
    }
    for (size_t i = 0; i < nout; i++) {
        char *name = NULL;
        int which;
        ORT_CHECK(ctx->ort->SessionGetOutputName(ctx->sess, i, alloc, &name),
                  "SessionGetOutputName");
        which = strcmp(name, "euler_deg") == 0 ? 0 : strcmp(name, "rotmat") == 0 ? 1 : -1;
        alloc->Free(alloc, name);
        if (which < 0) continue;
        if (io_shape(ctx, 0, i, dims, &nd, &type, err) < 0) goto fail;
        shape_str(dims, nd, shp, sizeof shp);
        if (type != ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT ||
            !shape_matches(dims, nd, which ? want_r : want_e, which ? 3 : 2)) {
            pi_seterr(err, "pi_open(%s): model output \"%s\" is %s, expected float32 %s", model,
                      which ? "rotmat" : "euler_deg", shp, which ? "[N,3,3]" : "[N,3]");
            goto fail;
        }
        if (which == 0)
            found_e = 1;
        else
            ctx->has_rotmat = 1;
    }
    if (!found_e) {
        pi_seterr(err, "pi_open(%s): model has no output \"euler_deg\"", model);
        goto fail;
    }
    return 0;
fail:
    return -1;
}

/* Copy all custom metadata; check spherepose.preprocess. */
static int read_metadata(pi_ctx *ctx, const char *model, char *err)
{
    OrtModelMetadata *md = NULL;
    OrtAllocator *alloc = NULL;
    char **keys = NULL;
    int64_t nkeys = 0;
    int found = 0;

    ORT_CHECK(ctx->ort->GetAllocatorWithDefaultOptions(&alloc), "GetAllocatorWithDefaultOptions");
    ORT_CHECK(ctx->ort->SessionGetModelMetadata(ctx->sess, &md), "SessionGetModelMetadata");
    ORT_CHECK(ctx->ort->ModelMetadataGetCustomMetadataMapKeys(md, alloc, &keys, &nkeys),
              "ModelMetadataGetCustomMetadataMapKeys");
    if (nkeys > 0) {
        ctx->meta_keys = calloc((size_t)nkeys, sizeof(char *));
        ctx->meta_vals = calloc((size_t)nkeys, sizeof(char *));
        if (!ctx->meta_keys || !ctx->meta_vals) {
            pi_seterr(err, "pi_open(%s): out of memory", model);
            goto fail;
        }
    }
    for (int64_t i = 0; i < nkeys; i++) {
        char *val = NULL;
        OrtStatus *st = ctx->ort->ModelMetadataLookupCustomMetadataMap(md, alloc, keys[i], &val);
        if (st) {
            ort_fail(ctx->ort, st, err, "ModelMetadataLookupCustomMetadataMap");
            goto fail;
        }
        ctx->meta_keys[ctx->nmeta] = strdup(keys[i]);
        ctx->meta_vals[ctx->nmeta] = strdup(val ? val : "");
        ctx->nmeta++;
        if (val) alloc->Free(alloc, val);
        if (!ctx->meta_keys[ctx->nmeta - 1] || !ctx->meta_vals[ctx->nmeta - 1]) {
            pi_seterr(err, "pi_open(%s): out of memory", model);
            goto fail;
        }
    }
    for (size_t i = 0; i < ctx->nmeta; i++) {
        if (strcmp(ctx->meta_keys[i], META_PREPROCESS) == 0) {
            found = 1;
            if (pi_parse_preprocess(ctx->meta_vals[i], &ctx->pp, err, model) < 0) goto fail;
        }
    }
    if (!found) {
        pi_seterr(
            err,
            "pi_open(%s): model has no metadata key %s (the preprocessing it was trained with)",
            model, META_PREPROCESS);
        goto fail;
    }
    for (int64_t i = 0; i < nkeys; i++) alloc->Free(alloc, keys[i]);
    if (keys) alloc->Free(alloc, keys);
    ctx->ort->ReleaseModelMetadata(md);
    return 0;
fail:
    for (int64_t i = 0; keys && i < nkeys; i++) alloc->Free(alloc, keys[i]);
    if (keys) alloc->Free(alloc, keys);
    if (md) ctx->ort->ReleaseModelMetadata(md);
    return -1;
}

static int run_model(pi_ctx *ctx, char *err)
{
    static const char *in_names[] = {"image"};
    static const char *out_names[] = {"euler_deg", "rotmat"};
    ORT_CHECK(ctx->ort->Run(ctx->sess, NULL, in_names, (const OrtValue *const *)&ctx->in_val, 1,
                            out_names, ctx->has_rotmat ? 2 : 1, ctx->out_val),
              "OrtRun");
    return 0;
fail:
    return -1;
}

/* The per-thread part of a context: tensors that wrap buffers allocated
 * once (Run writes into them), and the decode holder. */
static int make_io(pi_ctx *ctx, char *err)
{
    const int64_t S = ctx->pp.size;
    const int64_t in_shape[4] = {1, 3, S, S}, e_shape[2] = {1, 3}, r_shape[3] = {1, 3, 3};
    size_t n = (size_t)(3 * S * S);
    ctx->in_buf = calloc(n, sizeof(float));
    if (!ctx->in_buf) {
        pi_seterr(err, "pi_open: out of memory");
        goto fail;
    }
    ORT_CHECK(ctx->ort->CreateCpuMemoryInfo(OrtArenaAllocator, OrtMemTypeDefault, &ctx->mem),
              "CreateCpuMemoryInfo");
    ORT_CHECK(ctx->ort->CreateTensorWithDataAsOrtValue(
                  ctx->mem, ctx->in_buf, n * sizeof(float), in_shape, 4,
                  ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &ctx->in_val),
              "CreateTensorWithDataAsOrtValue");
    ORT_CHECK(ctx->ort->CreateTensorWithDataAsOrtValue(
                  ctx->mem, ctx->euler, sizeof ctx->euler, e_shape, 2,
                  ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &ctx->out_val[0]),
              "CreateTensorWithDataAsOrtValue");
    if (ctx->has_rotmat)
        ORT_CHECK(ctx->ort->CreateTensorWithDataAsOrtValue(
                      ctx->mem, ctx->rot, sizeof ctx->rot, r_shape, 3,
                      ONNX_TENSOR_ELEMENT_DATA_TYPE_FLOAT, &ctx->out_val[1]),
                  "CreateTensorWithDataAsOrtValue");
    ctx->mat = shim_mat_new();
    ctx->und = shim_mat_new();
    if (!ctx->mat || !ctx->und) {
        pi_seterr(err, "pi_open: out of memory");
        goto fail;
    }
    return 0;
fail:
    return -1;
}

pi_ctx *pi_open(const char *model_path, const pi_options *opt, char *err)
{
    pi_ctx *ctx = NULL;
    pi_options def;
    struct stat sb;
    const int64_t one = 1;

    if (!opt) {
        pi_options_init(&def);
        opt = &def;
    }
    if (!model_path) {
        pi_seterr(err, "pi_open: no model path");
        return NULL;
    }
    /* ORT's own message for a missing file is long; say it plainly. */
    if (stat(model_path, &sb) < 0) {
        pi_seterr(err, "pi_open(%s): %s", model_path, strerror(errno));
        return NULL;
    }
    if (!S_ISREG(sb.st_mode)) {
        pi_seterr(err, "pi_open(%s): not a regular file", model_path);
        return NULL;
    }
    ctx = calloc(1, sizeof *ctx);
    if (!ctx) {
        pi_seterr(err, "pi_open: out of memory");
        return NULL;
    }
    ctx->refs = 1;
    ctx->max_pixels = opt->max_pixels > 0 ? opt->max_pixels : PI_DEFAULT_MAX_PIXELS;
    ctx->ort = OrtGetApiBase()->GetApi(ORT_API_VERSION);
    if (!ctx->ort) {
        pi_seterr(err, "OrtGetApiBase: runtime %s does not serve API version %d",
                  OrtGetApiBase()->GetVersionString(), ORT_API_VERSION);
        free(ctx);
        return NULL;
    }
    ORT_CHECK(ctx->ort->CreateEnv(ORT_LOGGING_LEVEL_ERROR, "poseinfer", &ctx->env), "CreateEnv");
    ORT_CHECK(ctx->ort->CreateSessionOptions(&ctx->opts), "CreateSessionOptions");
    /* One frame at a time: a small, fixed pool; no spinning so that an idle
     * daemon uses no CPU; sequential execution. */
    ORT_CHECK(
        ctx->ort->SetIntraOpNumThreads(ctx->opts, opt->intra_threads > 0 ? opt->intra_threads : 1),
        "SetIntraOpNumThreads");
    ORT_CHECK(ctx->ort->SetInterOpNumThreads(ctx->opts, 1), "SetInterOpNumThreads");
    ORT_CHECK(ctx->ort->SetSessionExecutionMode(ctx->opts, ORT_SEQUENTIAL),
              "SetSessionExecutionMode");
    ORT_CHECK(ctx->ort->SetSessionGraphOptimizationLevel(ctx->opts, ORT_ENABLE_ALL),
              "SetSessionGraphOptimizationLevel");
    ORT_CHECK(ctx->ort->AddSessionConfigEntry(ctx->opts, "session.intra_op.allow_spinning", "0"),
              "AddSessionConfigEntry");
    ORT_CHECK(ctx->ort->AddSessionConfigEntry(ctx->opts, "session.inter_op.allow_spinning", "0"),
              "AddSessionConfigEntry");
    {
        OrtStatus *st = ctx->ort->CreateSession(ctx->env, model_path, ctx->opts, &ctx->sess);
        if (st) {
            char call[PI_ERR_LEN];
            snprintf(call, sizeof call, "pi_open(%s): CreateSession", model_path);
            ort_fail(ctx->ort, st, err, call);
            goto fail;
        }
    }
    if (read_metadata(ctx, model_path, err) < 0) goto fail;
    if (opt->camera_file && load_camera(ctx, model_path, opt->camera_file, err) < 0) goto fail;
    if (check_contract(ctx, model_path, err) < 0) goto fail;
    if (setup_refine(ctx, model_path, opt, err) < 0) goto fail;

    (void)one;
    if (make_io(ctx, err) < 0) goto fail;

    /* Warm-up: the first Run allocates and plans; do it now, not on the
     * first frame. */
    for (int i = 0; i < (opt->warmup_runs > 0 ? opt->warmup_runs : 0); i++)
        if (run_model(ctx, err) < 0) goto fail;
    return ctx;
fail:
    pi_close(ctx);
    return NULL;
}

/* Free the per-thread part (make_io), and the read buffer. */
static void release_io(pi_ctx *ctx)
{
    if (ctx->ort) {
        if (ctx->out_val[1]) ctx->ort->ReleaseValue(ctx->out_val[1]);
        if (ctx->out_val[0]) ctx->ort->ReleaseValue(ctx->out_val[0]);
        if (ctx->in_val) ctx->ort->ReleaseValue(ctx->in_val);
        if (ctx->mem) ctx->ort->ReleaseMemoryInfo(ctx->mem);
    }
    free(ctx->in_buf);
    free(ctx->filebuf);
    shim_mat_free(ctx->mat);
    shim_mat_free(ctx->und);
    rf_work_free(ctx->rf_w);
}

static void destroy(pi_ctx *ctx)
{
    release_io(ctx);
    shim_camera_free(&ctx->pp);
    if (ctx->ort) {
        if (ctx->sess) ctx->ort->ReleaseSession(ctx->sess);
        if (ctx->opts) ctx->ort->ReleaseSessionOptions(ctx->opts);
        if (ctx->env) ctx->ort->ReleaseEnv(ctx->env);
    }
    for (size_t i = 0; i < ctx->nmeta; i++) {
        free(ctx->meta_keys[i]);
        free(ctx->meta_vals[i]);
    }
    free(ctx->meta_keys);
    free(ctx->meta_vals);
    rf_texture_free(ctx->rf_tex);
    free(ctx);
}

/* The session is freed with the last context that uses it. */
static void unref(pi_ctx *base)
{
    if (__atomic_sub_fetch(&base->refs, 1, __ATOMIC_ACQ_REL) == 0) destroy(base);
}

void pi_close(pi_ctx *ctx)
{
    if (!ctx) return;
    if (ctx->parent) {
        pi_ctx *base = ctx->parent;
        release_io(ctx);
        free(ctx);
        unref(base);
    } else {
        unref(ctx);
    }
}

pi_ctx *pi_clone(pi_ctx *base, char *err)
{
    pi_ctx *ctx;
    if (!base) {
        pi_seterr(err, "pi_clone: no model");
        return NULL;
    }
    if (base->parent) base = base->parent;
    ctx = malloc(sizeof *ctx);
    if (!ctx) {
        pi_seterr(err, "pi_clone: out of memory");
        return NULL;
    }
    /* Everything read-only is shared with the base (session, parameters,
     * metadata); the buffers are the clone's own. */
    *ctx = *base;
    ctx->parent = base;
    ctx->env = NULL;
    ctx->opts = NULL;
    ctx->mem = NULL;
    ctx->in_val = ctx->out_val[0] = ctx->out_val[1] = NULL;
    ctx->in_buf = NULL;
    ctx->mat = NULL;
    ctx->und = NULL;
    ctx->filebuf = NULL;
    ctx->filecap = 0;
    ctx->rf_w = NULL;
    ctx->frame_bytes = 0;
    ctx->nmeta = 0;
    ctx->meta_keys = ctx->meta_vals = NULL;
    __atomic_add_fetch(&base->refs, 1, __ATOMIC_ACQ_REL);
    if (make_io(ctx, err) < 0) {
        pi_close(ctx);
        return NULL;
    }
    return ctx;
}

int pi_release_large(pi_ctx *ctx, size_t over)
{
    int freed = 0;
    if (!ctx) return 0;
    if (ctx->filecap > over) {
        free(ctx->filebuf);
        ctx->filebuf = NULL;
        ctx->filecap = 0;
        freed = 1;
    }
    if (ctx->frame_bytes > over) {
        shim_mat *m = shim_mat_new();
        if (m) {
            shim_mat_free(ctx->mat);
            ctx->mat = m;
            ctx->frame_bytes = 0;
            freed = 1;
        }
    }
    return freed;
}

int pi_input_size(const pi_ctx *ctx)
{
    return ctx ? ctx->pp.size : 0;
}

const char *pi_cpu_paths(void)
{
    /* the refinement's versions and names: refine.h RF_VERSION_LIST */
#define PI_LOC_PORTABLE(id, name) "localisation portable, refinement " name,
#define PI_LOC_AVX512(id, name)   "localisation AVX-512, refinement " name,
    static const char *const paths[2][RF_V_COUNT] = {{RF_VERSION_LIST(PI_LOC_PORTABLE)},
                                                     {RF_VERSION_LIST(PI_LOC_AVX512)}};
#undef PI_LOC_PORTABLE
#undef PI_LOC_AVX512
    const int v = rf_version_in_use();
    return paths[shim_crop2_avx512() != 0][v >= 0 && v < RF_V_COUNT ? v : 0];
}

const char *pi_metadata(const pi_ctx *ctx, const char *key)
{
    if (!ctx || !key) return NULL;
    if (ctx->parent) ctx = ctx->parent;
    for (size_t i = 0; i < ctx->nmeta; i++)
        if (strcmp(ctx->meta_keys[i], key) == 0) return ctx->meta_vals[i];
    return NULL;
}

/* ---- inference ----------------------------------------------------------- */

/* pi_preprocess_frame; *seen (when not NULL) is the frame the circle lies in,
 * the undistorted one with a camera that has distortion (held in ctx->und). */
static int preprocess(pi_ctx *ctx, const pi_frame *frame, float *out, size_t n, pi_result *res,
                      pi_frame *seen, char *err)
{
    pp_circle c = {0};
    pi_frame tmpf;
    double t0 = pi_now_ms();
    memset(res, 0, sizeof *res);
    if (!ctx || !frame || !frame->data) {
        pi_seterr(err, "pi_preprocess_frame: no frame");
        return -1;
    }
    if (n < (size_t)3 * ctx->pp.size * ctx->pp.size) {
        pi_seterr(err, "pi_preprocess_frame: output buffer too small");
        return -1;
    }
    if (frame->width <= 0 || frame->height <= 0 ||
        (double)frame->width * frame->height > (double)ctx->max_pixels) {
        pi_seterr(err, "pi_preprocess_frame: frame is %dx%d, outside 1..%ld pixels", frame->width,
                  frame->height, ctx->max_pixels);
        return -1;
    }
    res->width = frame->width;
    res->height = frame->height;
    res->decode_ms = frame->decode_ms;
    if (shim_preprocess_seen(frame, &ctx->pp, out, &c, seen ? ctx->und : NULL, seen ? seen : &tmpf,
                             err) < 0)
        return -1;
    res->cx = c.cx;
    res->cy = c.cy;
    res->r = c.r;
    res->circle[0] = c.cx + 0.5; /* the conventions' continuous pixels */
    res->circle[1] = c.cy + 0.5;
    res->circle[2] = c.r;
    res->locate_ms = c.locate_ms;
    memcpy(ctx->loc_cov, c.cov, sizeof ctx->loc_cov);
    res->preprocess_ms = pi_now_ms() - t0;
    return 0;
}

int pi_preprocess_frame(pi_ctx *ctx, const pi_frame *frame, float *out, size_t n, pi_result *res,
                        char *err)
{
    pi_result tmp;
    return preprocess(ctx, frame, out, n, res ? res : &tmp, NULL, err);
}

int pi_run_only(pi_ctx *ctx, char *err)
{
    if (!ctx) {
        pi_seterr(err, "pi_run_only: no model");
        return -1;
    }
    return run_model(ctx, err);
}

/* ---- refinement and confidence (docs/refine.md) ---------------------------- */

/* The texture and thresholds of the model; a model without a texture runs
 * unrefined, which is said once per process. */
static int setup_refine(pi_ctx *ctx, const char *model, const pi_options *opt, char *err)
{
    static int told;
    const char *b64 = pi_metadata(ctx, RF_META_TEXTURE);
    char rerr[PI_ERR_LEN];
    ctx->rf_on = !opt->no_refine;
    ctx->rf_focal = opt->focal_px > 0 ? opt->focal_px : 0;
    /* the camera file's focal length, when one was given (sphere-crop-v2) */
    if (!ctx->rf_focal && ctx->pp.cam.set && ctx->pp.cam.pixel_mm > 0)
        ctx->rf_focal = ctx->pp.cam.focal_mm / ctx->pp.cam.pixel_mm;
    rf_conf_defaults(&ctx->rf_conf);
    if (rf_conf_parse(&ctx->rf_conf, pi_metadata(ctx, RF_META_CONFIDENCE),
                      pi_metadata(ctx, "spherepose.ranges"), rerr, sizeof rerr) < 0) {
        pi_seterr(err, "pi_open(%s): %s", model, rerr);
        return -1;
    }
    if (!b64) {
        if (!told++)
            fprintf(stderr,
                    "poseinfer: %s carries no texture (metadata %s): angles are not refined and "
                    "have no confidence; add it with python -m training.refine add-texture\n",
                    model, RF_META_TEXTURE);
        return 0;
    }
    unsigned char *png = NULL;
    size_t len = 0;
    shim_mat *m = NULL;
    pi_frame tf;
    if (rf_base64_decode(b64, &png, &len) < 0) {
        pi_seterr(err, "pi_open(%s): metadata %s: not base64", model, RF_META_TEXTURE);
        return -1;
    }
    m = shim_mat_new();
    if (!m || shim_decode(m, png, len, 64L * 1024 * 1024, &tf, rerr) < 0) {
        pi_seterr(err, "pi_open(%s): metadata %s: %s", model, RF_META_TEXTURE,
                  m ? rerr : "out of memory");
        goto fail;
    }
    {
        rf_image ti = {tf.data, tf.width, tf.height, tf.channels, tf.stride};
        ctx->rf_tex = rf_texture_new(&ti, rerr);
    }
    if (!ctx->rf_tex) {
        pi_seterr(err, "pi_open(%s): metadata %s: %s", model, RF_META_TEXTURE, rerr);
        goto fail;
    }
    shim_mat_free(m);
    free(png);
    return 0;
fail:
    shim_mat_free(m);
    free(png);
    return -1;
}

/* The circle after refinement (docs/refine.md, steps 8 and 9; training/refine.py
 * printed_circle): the texture fixes the refined radius within about 0.1 %;
 * where it differs from the localisation's by more than RF_RIM_CHECK_PCT %,
 * the localisation's circle is likely off, and the rim found from the refined
 * circle is the sphere's (the localisation's stands when shim_rim_from finds
 * no rim or fails). That circle's centre is then weighed against the refined
 * centre by its rims' covariance (rf_fused_centre): the localisation's
 * (ctx->loc_cov) or the rim's; unchanged when there is none (NaN) or it or
 * the refined centre is not finite.
 * sphere-crop-v2 only. */
static void printed_circle(pi_ctx *ctx, const pi_frame *frame, pi_result *res)
{
    char rerr[PI_ERR_LEN];
    double cx = res->cx, cy = res->cy, r = res->r, cov[3];
    if (ctx->pp.version != 2) return;
    memcpy(cov, ctx->loc_cov, sizeof cov);
    if (100.0 * fabs(res->rr / res->r - 1.0) > RF_RIM_CHECK_PCT) {
        double rx, ry, rrad, rcov[3];
        if (shim_rim_from(frame, &ctx->pp, res->rcx - 0.5, res->rcy - 0.5, res->rr, &rx, &ry, &rrad,
                          rcov, rerr) == 0) {
            cx = rx;
            cy = ry;
            r = rrad;
            memcpy(cov, rcov, sizeof cov);
        }
    }
    if (isfinite(cov[0]) && isfinite(cov[1]) && isfinite(cov[2]) && isfinite(res->rcx) &&
        isfinite(res->rcy))
        rf_fused_centre(cx, cy, cov, res->rcx - 0.5, res->rcy - 0.5, &cx, &cy);
    res->circle[0] = cx + 0.5;
    res->circle[1] = cy + 0.5;
    res->circle[2] = r;
}

/* Refine the network's angles (or only measure the residual at them) and
 * judge them. A failed refinement is a result that is not confident, not an
 * error: the network's angles still stand. */
static void refine_result(pi_ctx *ctx, const pi_frame *frame, pi_result *res)
{
    char rerr[sizeof res->note];
    double t0 = pi_now_ms(), R0[3][3], moved;
    rf_out o;
    res->net[0] = res->x;
    res->net[1] = res->y;
    res->net[2] = res->z;
    res->has_confidence = 0;
    res->refined = 0;
    res->note[0] = 0;
    if (!ctx->rf_tex) return;
    res->has_confidence = 1;
    res->confident = 0;
    res->residual = NAN;
    if (!ctx->rf_w && !(ctx->rf_w = rf_work_new())) {
        snprintf(res->note, sizeof res->note, "refinement: out of memory");
        return;
    }
    sp_euler_to_matrix(res->net, R0);
    {
        rf_image fi = {frame->data, frame->width, frame->height, frame->channels,
                       frame->stride ? frame->stride : (size_t)frame->width * frame->channels};
        /* the localisation's circle is in OpenCV's pixel coordinates (centres
         * at integers); refinement works in the conventions' (centres at +0.5) */
        if (rf_refine_checked(ctx->rf_tex, ctx->rf_w, &fi, res->cx + 0.5, res->cy + 0.5,
                              res->r + 0.5, R0, ctx->rf_focal, ctx->rf_on,
                              ctx->rf_conf.converge_max_deg, &o, &moved, rerr, sizeof rerr) < 0) {
            snprintf(res->note, sizeof res->note, "%s", rerr);
            res->refine_ms = pi_now_ms() - t0;
            return;
        }
    }
    res->residual = o.residual;
    if (ctx->rf_on) {
        res->refined = 1;
        res->x = o.euler[0];
        res->y = o.euler[1];
        res->z = o.euler[2];
        res->rcx = o.cx;
        res->rcy = o.cy;
        res->rr = o.r;
        if (res->has_rotmat) memcpy(res->rotmat, o.R, sizeof o.R);
    }
    res->confident =
        rf_judge(&ctx->rf_conf, o.residual, o.colour, moved, ctx->rf_on ? o.euler : res->net,
                 ctx->rf_on, res->note, sizeof res->note);
    if (res->refined && res->confident) printed_circle(ctx, frame, res);
    res->refine_ms = pi_now_ms() - t0;
}

int pi_infer_frame(pi_ctx *ctx, const pi_frame *frame, pi_result *res, char *err)
{
    double t0 = pi_now_ms(), t1;
    pi_result tmp;
    pi_frame seen; /* refinement reads the frame the localisation saw */
    if (!res) res = &tmp;
    if (!ctx) {
        memset(res, 0, sizeof *res);
        pi_seterr(err, "pi_infer_frame: no model");
        return -1;
    }
    if (preprocess(ctx, frame, ctx->in_buf, (size_t)3 * ctx->pp.size * ctx->pp.size, res, &seen,
                   err) < 0)
        return -1;
    t1 = pi_now_ms();
    if (run_model(ctx, err) < 0) return -1;
    res->infer_ms = pi_now_ms() - t1;
    for (int i = 0; i < 3; i++) {
        if (!isfinite(ctx->euler[i])) {
            pi_seterr(err, "OrtRun: model output is not finite");
            return -1;
        }
    }
    res->x = ctx->euler[0];
    res->y = ctx->euler[1];
    res->z = ctx->euler[2];
    res->has_rotmat = ctx->has_rotmat;
    if (ctx->has_rotmat)
        for (int i = 0; i < 9; i++) res->rotmat[i / 3][i % 3] = ctx->rot[i];
    refine_result(ctx, &seen, res);
    res->total_ms = res->decode_ms + (pi_now_ms() - t0);
    return 0;
}

int pi_infer_bgr(pi_ctx *ctx, const uint8_t *bgr, int width, int height, size_t stride,
                 pi_result *res, char *err)
{
    pi_frame f = {bgr, width, height, 3, stride, 0};
    return pi_infer_frame(ctx, &f, res, err);
}

int pi_decode_into(shim_mat *m, const void *buf, size_t len, long max_pixels, pi_frame *f,
                   char *err)
{
    double t0 = pi_now_ms();
    if (shim_decode(m, buf, len, max_pixels, f, err) < 0) return -1;
    f->decode_ms = pi_now_ms() - t0;
    return 0;
}

int pi_infer_memory(pi_ctx *ctx, const void *buf, size_t len, pi_result *res, char *err)
{
    pi_frame f;
    pi_result tmp;
    if (!res) res = &tmp;
    memset(res, 0, sizeof *res);
    if (!ctx || !buf) {
        pi_seterr(err, "pi_infer_memory: no data");
        return -1;
    }
    if (pi_decode_into(ctx->mat, buf, len, ctx->max_pixels, &f, err) < 0) return -1;
    ctx->frame_bytes = f.stride * (size_t)f.height;
    return pi_infer_frame(ctx, &f, res, err);
}

long pi_max_file_bytes = PI_DEFAULT_MAX_FILE_BYTES;

int pi_read_file(const char *path, unsigned char **buf, size_t *cap, size_t *len, char *err)
{
    int fd = -1;

    /* O_NONBLOCK: opening a FIFO (or a device) must not wait for a writer;
     * fstat on what was opened, so nothing is swapped in between. */
    fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY);
    if (fd < 0) {
        pi_seterr(err, "open(%s): %s", path, strerror(errno));
        goto fail;
    }
    return pi_read_fd(fd, path, buf, cap, len, err);
fail:
    return -1;
}

const char *pi_file_kind(unsigned mode)
{
    return S_ISDIR(mode)    ? "a directory"
           : S_ISFIFO(mode) ? "a FIFO"
           : S_ISSOCK(mode) ? "a socket"
           : S_ISCHR(mode)  ? "a character device"
           : S_ISBLK(mode)  ? "a block device"
                            : "not a regular file";
}

int pi_read_fd(int fd, const char *path, unsigned char **buf, size_t *cap, size_t *len, char *err)
{
    struct stat sb;
    size_t got = 0;
    long max_bytes = pi_max_file_bytes;

    if (fstat(fd, &sb) < 0) {
        pi_seterr(err, "fstat(%s): %s", path, strerror(errno));
        goto fail;
    }
    if (!S_ISREG(sb.st_mode)) {
        pi_seterr(err, "open(%s): not a regular file (%s)", path, pi_file_kind(sb.st_mode));
        goto fail;
    }
    if (sb.st_size > max_bytes) {
        pi_seterr(err, "open(%s): file of %lld bytes, over the limit of %ld", path,
                  (long long)sb.st_size, max_bytes);
        goto fail;
    }
    if ((size_t)sb.st_size + 1 > *cap) {
        unsigned char *nb = realloc(*buf, (size_t)sb.st_size + 1);
        if (!nb) {
            pi_seterr(err, "open(%s): out of memory", path);
            goto fail;
        }
        *buf = nb;
        *cap = (size_t)sb.st_size + 1;
    }
    while (got < (size_t)sb.st_size) {
        ssize_t r = read(fd, *buf + got, (size_t)sb.st_size - got);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) {
            pi_seterr(err, "read(%s): %s", path, strerror(errno));
            goto fail;
        }
        if (r == 0) break;
        got += (size_t)r;
    }
    close(fd);
    *len = got;
    return 0;
fail:
    if (fd >= 0) close(fd);
    return -1;
}

int pi_load_file(pi_ctx *ctx, const char *path, pi_frame *f, char *err)
{
    if (!ctx || !path || !f) {
        pi_seterr(err, "pi_load_file: no file");
        return -1;
    }
    return pi_load_fd(ctx, -1, path, f, err);
}

int pi_load_fd(pi_ctx *ctx, int fd, const char *path, pi_frame *f, char *err)
{
    double t0 = pi_now_ms();
    size_t len = 0;
    if (fd >= 0 ? pi_read_fd(fd, path, &ctx->filebuf, &ctx->filecap, &len, err) < 0
                : pi_read_file(path, &ctx->filebuf, &ctx->filecap, &len, err) < 0)
        return -1;
    if (shim_decode(ctx->mat, ctx->filebuf, len, ctx->max_pixels, f, err) < 0) {
        /* name the file: "decode(path): reason" */
        char tmp[PI_ERR_LEN];
        snprintf(tmp, sizeof tmp, "%s",
                 err && strncmp(err, "decode: ", 8) == 0 ? err + 8 : (err ? err : ""));
        pi_seterr(err, "decode(%s): %s", path, tmp);
        return -1;
    }
    f->decode_ms = pi_now_ms() - t0;
    ctx->frame_bytes = f->stride * (size_t)f->height;
    return 0;
}

int pi_infer_file(pi_ctx *ctx, const char *path, pi_result *res, char *err)
{
    pi_frame f;
    pi_result tmp;
    if (!res) res = &tmp;
    memset(res, 0, sizeof *res);
    if (!ctx || !path) {
        pi_seterr(err, "pi_infer_file: no file");
        return -1;
    }
    if (pi_load_file(ctx, path, &f, err) < 0) return -1;
    return pi_infer_frame(ctx, &f, res, err);
}

int pi_infer_fd(pi_ctx *ctx, int fd, const char *name, pi_result *res, char *err)
{
    pi_frame f;
    pi_result tmp;
    if (!res) res = &tmp;
    memset(res, 0, sizeof *res);
    if (!ctx || fd < 0) {
        if (fd >= 0) close(fd);
        pi_seterr(err, "pi_infer_fd: no file");
        return -1;
    }
    if (pi_load_fd(ctx, fd, name, &f, err) < 0) return -1;
    return pi_infer_frame(ctx, &f, res, err);
}

int pi_frame_save(const pi_frame *frame, const char *path, char *err)
{
    if (!frame || !frame->data || !path) {
        pi_seterr(err, "pi_frame_save: no frame");
        return -1;
    }
    return shim_save(frame, path, err);
}
