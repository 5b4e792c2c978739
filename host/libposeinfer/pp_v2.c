/* pp_v2.c -- the parameters of preprocessing "sphere-crop-v2" from a model's
 * metadata, and the camera file (docs/interfaces.md). A v2 model carries
 * every parameter (training/preprocess.py DEFAULTS_V2 is their one source);
 * a missing or unknown key is an error naming it, never a default. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "json.h"
#include "shim.h"

#define META "spherepose.preprocess"

enum kind { K_NUM, K_INT, K_TRIPLE };

struct key {
    const char *name;
    enum kind kind;
    double lo, hi;
    size_t off; /* offset in pp_params */
};

#define NUM(n, lo, hi)                            \
    {                                             \
#n, K_NUM, lo, hi, offsetof(pp_params, n) \
    }
#define INT(n, lo, hi)                            \
    {                                             \
#n, K_INT, lo, hi, offsetof(pp_params, n) \
    }

static const struct key keys[] = {
    INT(size, 8, 2048),
    NUM(margin, 0.5, 10),
    {"mean", K_TRIPLE, -1e9, 1e9, offsetof(pp_params, mean)},
    {"std", K_TRIPLE, 0, 1e9, offsetof(pp_params, std)},
    NUM(r_min_frac, 0, 1),
    NUM(r_max_frac, 0, 10),
    NUM(r_tol, 0, 0.9),
    INT(coarse_size, 8, 100000),
    NUM(coarse_rbin, 0, 10),
    NUM(edge_min, 0, 100000),
    INT(candidates, 1, 64),
    NUM(cand_frac, 0, 1),
    NUM(cand_gap, 0, 10),
    INT(rays, 8, 4096),
    NUM(ray_edge_min, 0, 1000),
    NUM(consensus_cells, 0, 64),
    NUM(consensus_px, 0, 256),
    NUM(consensus_step_px, 0.125, 64),
    NUM(consensus_reach, 1, 8),
    NUM(consensus_edge_ratio, 0, 100),
    INT(fine_passes, 1, 16),
    NUM(fine_window_px, 0.5, 256),
    NUM(fine_window_frac, 0, 1),
    INT(irls_iters, 1, 100),
    NUM(tukey_c, 0.1, 100),
    NUM(sigma_min_px, 0.001, 100),
    NUM(inlier_px, 0, 100),
    NUM(support_edge_min, 0, 1000),
    NUM(support_ratio, 0, 100),
    NUM(support_flank_px, 0.5, 256),
    NUM(min_support, 0, 1),
    NUM(max_cut, 0, 1),
    NUM(mask_frac, 0, 10),
    {"fill", K_TRIPLE, 0, 255, offsetof(pp_params, fill)},
};

int pp_parse_v2(const json_value *root, pp_params *p, char *err, const char *model)
{
    const size_t nk = sizeof keys / sizeof keys[0];
    memset(p, 0, sizeof *p);
    p->version = 2;
    for (size_t i = 0; i < root->count; i++) {
        int known = !strcmp(root->keys[i], "name");
        for (size_t k = 0; k < nk && !known; k++) known = !strcmp(root->keys[i], keys[k].name);
        if (!known) {
            pi_seterr(err, "pi_open(%s): metadata %s: unknown sphere-crop-v2 key \"%s\"", model,
                      META, root->keys[i]);
            return -1;
        }
    }
    for (size_t k = 0; k < nk; k++) {
        const struct key *ky = &keys[k];
        const json_value *v = json_get(root, ky->name);
        char *base = (char *)p + ky->off;
        if (!v) {
            pi_seterr(err,
                      "pi_open(%s): metadata %s: sphere-crop-v2 needs key \"%s\" (the model's "
                      "export wrote "
                      "no value for it)",
                      model, META, ky->name);
            return -1;
        }
        if (ky->kind == K_TRIPLE) {
            int ok = v->type == JSON_ARRAY && v->count == 3;
            for (size_t i = 0; ok && i < 3; i++)
                ok = v->items[i].type == JSON_NUMBER && v->items[i].number >= ky->lo &&
                     v->items[i].number <= ky->hi &&
                     (strcmp(ky->name, "std") != 0 || v->items[i].number > 0);
            if (!ok) {
                pi_seterr(err, "pi_open(%s): metadata %s: \"%s\" must be 3 numbers in [%g, %g]%s",
                          model, META, ky->name, ky->lo, ky->hi,
                          strcmp(ky->name, "std") ? "" : ", > 0");
                return -1;
            }
            for (size_t i = 0; i < 3; i++) {
                if (!strcmp(ky->name, "fill"))
                    ((double *)base)[i] = v->items[i].number;
                else
                    ((float *)base)[i] = (float)v->items[i].number;
            }
            continue;
        }
        if (v->type != JSON_NUMBER || !(v->number >= ky->lo && v->number <= ky->hi) ||
            (ky->kind == K_INT && v->number != floor(v->number))) {
            pi_seterr(err, "pi_open(%s): metadata %s: \"%s\" must be %s in [%g, %g]", model, META,
                      ky->name, ky->kind == K_INT ? "an integer" : "a number", ky->lo, ky->hi);
            return -1;
        }
        if (ky->kind == K_INT)
            *(int *)base = (int)v->number;
        else
            *(double *)base = v->number;
    }
    if (p->rays % 8 != 0) {
        pi_seterr(err, "pi_open(%s): metadata %s: \"rays\" must be a multiple of 8", model, META);
        return -1;
    }
    if (!(p->r_min_frac <= p->r_max_frac)) {
        pi_seterr(err, "pi_open(%s): metadata %s: \"r_min_frac\" must not exceed \"r_max_frac\"",
                  model, META);
        return -1;
    }
    return 0;
}

/* ---- camera file ------------------------------------------------------------ */

static const char *cam_keys[] = {"width",        "height",      "focal_mm",
                                 "pixel_mm",     "distance_mm", "sphere_diameter_mm",
                                 "principal_px", "distortion",  NULL};

/* As sim/camera.py check_distortion: the lens model must be one-to-one over
 * the frame (the distorted radius growing along the diagonal, a tenth
 * beyond the farthest corner), its tangential terms below 10 % there. */
static int check_distortion(const pp_camera *cam, const char *path, char *err)
{
    const double k1 = cam->distortion[0], k2 = cam->distortion[1], p1 = cam->distortion[2],
                 p2 = cam->distortion[3], k3 = cam->distortion[4];
    const double u0 = cam->has_principal ? cam->principal[0] : cam->width / 2.0;
    const double v0 = cam->has_principal ? cam->principal[1] : cam->height / 2.0;
    const double f = cam->focal_mm / cam->pixel_mm;
    const double cx[4] = {0, cam->width, 0, cam->width}, cy[4] = {0, 0, cam->height, cam->height};
    double r_max = 0;
    for (int i = 0; i < 4; i++) r_max = fmax(r_max, hypot(cx[i] - u0, cy[i] - v0));
    r_max = r_max / f * 1.1;
    double prev = 0;
    for (int i = 1; i < 200; i++) {
        const double r = r_max * i / 199, r2 = r * r;
        const double rd = r * (1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2);
        if (!(rd > prev)) {
            pi_seterr(err,
                      "camera file %s: key \"distortion\": the radial terms fold the image over "
                      "within the "
                      "frame (distorted radius not increasing); not a usable calibration",
                      path);
            return -1;
        }
        prev = rd;
    }
    if (r_max > 0 && 2.0 * hypot(p1, p2) * r_max > 0.1) {
        pi_seterr(err,
                  "camera file %s: key \"distortion\": tangential terms p1, p2 move the frame's "
                  "corners by "
                  "more than 10 %%; not a usable calibration",
                  path);
        return -1;
    }
    return 0;
}

int pp_camera_load(const char *path, pp_camera *cam, char *err)
{
    unsigned char *buf = NULL;
    size_t cap = 0, len = 0;
    json_value root;
    char jerr[128];
    int rc = -1;
    memset(cam, 0, sizeof *cam);
    /* the reference camera for missing keys: tests/data/conventions_vectors.json
     * "camera" (tests/host/unit/test_camera_ref.c holds these to it) */
    cam->width = 640;
    cam->height = 512;
    cam->focal_mm = 16.0;
    cam->pixel_mm = 0.0096;
    cam->distance_mm = 250.0;
    cam->sphere_diameter_mm = 40.0;
    if (pi_read_file(path, &buf, &cap, &len, err) < 0) return -1;
    buf[len] = '\0';
    if (strlen((char *)buf) != len) {
        pi_seterr(err, "camera file %s: not a JSON text (NUL byte)", path);
        free(buf);
        return -1;
    }
    if (json_parse((char *)buf, &root, jerr, sizeof jerr) < 0) {
        pi_seterr(err, "camera file %s: %s", path, jerr);
        free(buf);
        return -1;
    }
    free(buf);
    if (root.type != JSON_OBJECT) {
        pi_seterr(
            err,
            "camera file %s: expected a JSON object with keys width, height, focal_mm, pixel_mm, "
            "distance_mm, sphere_diameter_mm, principal_px, distortion",
            path);
        goto out;
    }
    for (size_t i = 0; i < root.count; i++) {
        const char *k = root.keys[i];
        const json_value *v = &root.items[i];
        int known = 0;
        for (int j = 0; cam_keys[j]; j++) known |= !strcmp(k, cam_keys[j]);
        if (!known) {
            pi_seterr(err,
                      "camera file %s: unknown key \"%s\" (valid keys: width, height, focal_mm, "
                      "pixel_mm, "
                      "distance_mm, sphere_diameter_mm, principal_px, distortion)",
                      path, k);
            goto out;
        }
        if (!strcmp(k, "principal_px") || !strcmp(k, "distortion")) {
            const size_t n = !strcmp(k, "principal_px") ? 2 : 5;
            int ok = v->type == JSON_ARRAY && v->count == n;
            for (size_t j = 0; ok && j < n; j++)
                ok = v->items[j].type == JSON_NUMBER && isfinite(v->items[j].number);
            if (!ok) {
                pi_seterr(err, "camera file %s: key \"%s\" must be a list of %zu finite numbers",
                          path, k, n);
                goto out;
            }
            for (size_t j = 0; j < n; j++) {
                if (n == 2)
                    cam->principal[j] = v->items[j].number;
                else
                    cam->distortion[j] = v->items[j].number;
            }
            if (n == 2) cam->has_principal = 1;
            continue;
        }
        if (v->type != JSON_NUMBER || !isfinite(v->number) || !(v->number > 0)) {
            pi_seterr(err, "camera file %s: key \"%s\" must be a positive finite number", path, k);
            goto out;
        }
        if (!strcmp(k, "width") || !strcmp(k, "height")) {
            if (v->number != floor(v->number) || v->number > 16384) {
                pi_seterr(err,
                          "camera file %s: key \"%s\" must be a whole number of pixels up to 16384",
                          path, k);
                goto out;
            }
            if (!strcmp(k, "width"))
                cam->width = (int)v->number;
            else
                cam->height = (int)v->number;
        } else if (!strcmp(k, "focal_mm"))
            cam->focal_mm = v->number;
        else if (!strcmp(k, "pixel_mm"))
            cam->pixel_mm = v->number;
        else if (!strcmp(k, "distance_mm"))
            cam->distance_mm = v->number;
        else
            cam->sphere_diameter_mm = v->number;
    }
    if (!(cam->distance_mm > cam->sphere_diameter_mm / 2.0 * 1.05)) {
        pi_seterr(err,
                  "camera file %s: key \"distance_mm\" (%g) must exceed the sphere radius (%g) "
                  "with room to "
                  "spare: the camera would sit inside the sphere",
                  path, cam->distance_mm, cam->sphere_diameter_mm / 2.0);
        goto out;
    }
    for (int j = 0; j < 5; j++) cam->distorted |= cam->distortion[j] != 0.0;
    if (cam->distorted && check_distortion(cam, path, err) < 0) goto out;
    cam->set = 1;
    rc = 0;
out:
    json_free(&root);
    return rc;
}
