/* confidence.c -- the thresholds of metadata spherepose.confidence and
 * spherepose.ranges, and the judgement of one answer against them
 * (training/refine.py judge, the reference; docs/refine.md). */
#define _POSIX_C_SOURCE 200809L
#include "confidence.h"
#include "json.h"
#include "pi_err.h"

#include <math.h>
#include <stdio.h>

void rf_conf_defaults(rf_conf *c)
{
    c->residual_max = 0.25;
    c->residual_max_unrefined = 0.25;
    c->residual_max_gray = 0; /* residual_max */
    c->range_margin_deg = 2.0;
    c->colour_min = 0; /* no colour check */
    c->converge_max_deg = 0.3;
    for (int i = 0; i < 3; i++) {
        c->ranges[i][0] = -30;
        c->ranges[i][1] = 30;
    }
}

static int conf_number(const json_value *o, const char *key, double lo, double hi, double *out,
                       char *err, size_t errlen)
{
    const json_value *v = json_get(o, key);
    if (!v) return 0;
    if (v->type != JSON_NUMBER || !(v->number >= lo && v->number <= hi)) {
        pi_seterrn(err, errlen,
                   "metadata spherepose.confidence: \"%s\" must be a number in [%g, %g]", key, lo,
                   hi);
        return -1;
    }
    *out = v->number;
    return 0;
}

int rf_conf_parse(rf_conf *c, const char *confidence_json, const char *ranges_json, char *err,
                  size_t errlen)
{
    json_value root;
    char jerr[128];
    int has_unrefined = 0;
    if (confidence_json) {
        if (json_parse(confidence_json, &root, jerr, sizeof jerr) < 0) {
            pi_seterrn(err, errlen, "metadata spherepose.confidence: %s", jerr);
            return -1;
        }
        int bad = root.type != JSON_OBJECT;
        if (bad) pi_seterrn(err, errlen, "metadata spherepose.confidence: not a JSON object");
        if (!bad) {
            /* without its own threshold the unrefined residual uses the refined one */
            has_unrefined = json_get(&root, "residual_max_unrefined") != NULL;
            bad = conf_number(&root, "residual_max", 0, 1, &c->residual_max, err, errlen) < 0 ||
                  conf_number(&root, "residual_max_unrefined", 0, 1, &c->residual_max_unrefined,
                              err, errlen) < 0 ||
                  conf_number(&root, "range_margin_deg", 0, 180, &c->range_margin_deg, err,
                              errlen) < 0 ||
                  conf_number(&root, "colour_min", 0, 10, &c->colour_min, err, errlen) < 0 ||
                  conf_number(&root, "converge_max_deg", 0, 180, &c->converge_max_deg, err,
                              errlen) < 0 ||
                  conf_number(&root, "residual_max_gray", 0, 1, &c->residual_max_gray, err,
                              errlen) < 0;
            if (!has_unrefined) c->residual_max_unrefined = c->residual_max;
        }
        json_free(&root);
        if (bad) return -1;
    }
    if (ranges_json) {
        static const char *names[3] = {"x", "y", "z"};
        if (json_parse(ranges_json, &root, jerr, sizeof jerr) < 0) {
            pi_seterrn(err, errlen, "metadata spherepose.ranges: %s", jerr);
            return -1;
        }
        for (int i = 0; i < 3; i++) {
            const json_value *v = root.type == JSON_OBJECT ? json_get(&root, names[i]) : NULL;
            if (!v || v->type != JSON_ARRAY || v->count != 2 || v->items[0].type != JSON_NUMBER ||
                v->items[1].type != JSON_NUMBER || !(v->items[0].number <= v->items[1].number)) {
                pi_seterrn(err, errlen,
                           "metadata spherepose.ranges: \"%s\" must be [lo, hi] degrees", names[i]);
                json_free(&root);
                return -1;
            }
            c->ranges[i][0] = v->items[0].number;
            c->ranges[i][1] = v->items[1].number;
        }
        json_free(&root);
    }
    return 0;
}

int rf_judge(const rf_conf *c, double residual, double colour, double moved, const double euler[3],
             int refined, char *note, size_t notelen)
{
    double max = refined ? c->residual_max : c->residual_max_unrefined, m = c->range_margin_deg;
    if (refined && isnan(colour) && c->residual_max_gray > 0) max = c->residual_max_gray;
    if (!(residual <= max)) {
        snprintf(note, notelen,
                 "poor alignment (residual %.3f > %.3f): another texture, a pose outside the "
                 "model's ranges, or a wrong sphere",
                 residual, max);
        return 0;
    }
    if (!isnan(moved) && !(moved <= c->converge_max_deg)) {
        snprintf(note, notelen,
                 "not converged (a further pass moved it %.2f deg > %.2f): the start was too far "
                 "off (a mono camera, a circle found off the sphere)",
                 moved, c->converge_max_deg);
        return 0;
    }
    if (!isnan(colour) && c->colour_min > 0 && !(colour >= c->colour_min)) {
        snprintf(note, notelen,
                 "colours do not match (colour ratio %.2f < %.2f): another texture, or the "
                 "model's texture without its colours",
                 colour, c->colour_min);
        return 0;
    }
    for (int i = 0; i < 3; i++) {
        if (!(euler[i] >= c->ranges[i][0] - m && euler[i] <= c->ranges[i][1] + m)) {
            snprintf(note, notelen, "outside the model's ranges (%c = %.1f not in [%g, %g])",
                     "xyz"[i], euler[i], c -> ranges[i][0], c -> ranges[i][1]);
            return 0;
        }
    }
    if (notelen) note[0] = 0;
    return 1;
}
