/* confidence.h -- whether a refined (or unrefined) answer can be vouched
 * for: the thresholds of the model's metadata and the judgement
 * (training/refine.py judge is the reference; docs/refine.md). */
#ifndef PI_CONFIDENCE_H
#define PI_CONFIDENCE_H

#include "refine.h"

#include <stddef.h>

/* Confidence: thresholds (metadata spherepose.confidence) and the model's
 * ranges (spherepose.ranges). */
typedef struct rf_conf {
    double residual_max;           /* refined residual above this: not confident */
    double residual_max_gray;      /* the same for a gray frame (0: residual_max) */
    double residual_max_unrefined; /* the same for the residual at the network's pose */
    double range_margin_deg;       /* a pose this far beyond the ranges: not confident */
    double colour_min;       /* a colour frame's colour ratio below this: not confident (0: off) */
    double converge_max_deg; /* a checked answer's last pass rotated it more: not confident */
    double ranges[3][2];     /* x, y, z: [lo, hi] degrees */
} rf_conf;

void rf_conf_defaults(rf_conf *c);

/* Parse either JSON text (NULL: keep the defaults). -1 with err naming the key. */
int rf_conf_parse(rf_conf *c, const char *confidence_json, const char *ranges_json, char *err,
                  size_t errlen);

/* 1 when confident, else 0 with the reason in note (training/refine.py judge);
 * colour: rf_out.colour (NaN: a gray frame, no colour check, and when refined
 * residual_max_gray if set); moved: rf_refine_checked's (NaN: not checked). */
int rf_judge(const rf_conf *c, double residual, double colour, double moved, const double euler[3],
             int refined, char *note, size_t notelen);

#endif
