/* stage.h: the mechanical side of the simulated stage. Integrates STEP/DIR
 * pulses into motor positions, honours the drivers' enable line, drives the
 * limit-switch inputs, and keeps pulse-timing and interrupt-timing statistics.
 * Everything here runs inside the simulation thread (simavr IRQ hooks). */
#ifndef STAGE_H
#define STAGE_H

#include <stddef.h>
#include <stdint.h>
#include "sim_avr.h"
#include "err.h" /* ERR_LEN: err[] buffers */

#define STAGE_AXES    3
#define STAGE_VECTORS 32

struct stage;

struct stage_axis {
    struct stage *stage;
    int index;
    double steps_per_deg;
    long steps;                    /* position in steps, start offset included */
    uint64_t pulses;               /* rising edges that moved the motor */
    uint64_t ignored;              /* rising edges while disabled or not an output */
    int dir_level;                 /* last DIR pin level seen by the DIR hook */
    int dir_pending;               /* DIR changed since the last rising edge */
    uint64_t dir_change;           /* cycle of that change */
    uint64_t last_rise, last_fall; /* 0: none yet */
    uint64_t min_high, min_low, min_period, min_dir_setup; /* cycles; 0: none yet */
    uint64_t
        dir_violations; /* DIR changed in the same write as a rising STEP, or while STEP high */
    /* limit switch */
    int limit_enabled;
    double limit_deg; /* switch position */
    int limit_dir;    /* +1: active above limit_deg, -1: below */
    int limit_active;
    int limit_level_driven; /* pin level last driven, -1: never */
    int bounce_left;        /* contact bounces still to come */
    uint64_t limit_hits;    /* inactive -> active transitions */
};

struct stage_vector {
    uint64_t count;
    uint64_t entered; /* cycle of the last entry, 0: not running */
    uint64_t max_cycles, total_cycles;
};

struct stage {
    avr_t *avr;
    struct stage_axis axis[STAGE_AXES];
    int dir_invert_mask;    /* bit i: DIR high means positive on axis i */
    int step_invert_mask;   /* bit i: the step edge is the falling one */
    double limit_width;     /* degrees past the switch position it stays pressed; 0: forever */
    double limit_hyst;      /* degrees it must travel back to release */
    int bounce_count;       /* extra open/close pairs after each switch transition */
    uint32_t bounce_cycles; /* between two bounces */
    struct stage_vector vec[STAGE_VECTORS];
    avr_irq_t *limit_irq[STAGE_AXES];
    uint8_t limit_levels; /* port bits the switches drive (1 = open) */
    int trap_warned;      /* bit i: warned about timer i */
    /* longest stretch with interrupts disabled (SREG I clear), ISRs included */
    uint64_t cli_since; /* cycle I went clear, 0: I is set */
    uint32_t cli_pc;    /* where it went clear */
    uint64_t cli_max;
    uint32_t cli_max_pc;
};

/* Hook the STEP/DIR/limit pins and the interrupt vectors of a freshly
 * initialised atmega328p. Called once, before the first avr_run. */
int stage_attach(struct stage *s, avr_t *avr, char *err);

/* Drive the limit inputs again where the pin register disagrees with the
 * switch state (after a reset cleared it). Main loop, between avr_run calls. */
void stage_sync_limits(struct stage *s);

/* Warn once on stderr when the firmware sets up a timer in CTC mode with a
 * compare value of 0 and its interrupt enabled: simavr 1.6 never fires such a
 * compare (silicon does, every tick). Main loop, cheap. */
void stage_check_timer_traps(struct stage *s);

/* Track how long interrupts stay disabled. Main loop, after every avr_run
 * (one instruction), so it must stay this cheap. */
static inline void stage_note_sreg(struct stage *s)
{
    avr_t *avr = s->avr;
    if (!avr->sreg[S_I]) {
        if (!s->cli_since) {
            s->cli_since = avr->cycle ? avr->cycle : 1;
            s->cli_pc = avr->pc;
        }
    } else if (s->cli_since) {
        uint64_t d = avr->cycle - s->cli_since;
        if (d > s->cli_max) {
            s->cli_max = d;
            s->cli_max_pc = s->cli_pc;
        }
        s->cli_since = 0;
    }
}

/* 1 if the drivers are enabled now (PB0 an output driven low). */
int stage_enabled(const struct stage *s);

/* Mechanical angle of one axis in degrees. */
double stage_angle(const struct stage *s, int axis);

/* Format the `state` reply (one JSON line, with '\n') into buf. Returns length. */
size_t stage_format_state(const struct stage *s, char *buf, size_t len);

/* Format the `stats` reply (pulse timing, interrupt timing; one JSON line). */
size_t stage_format_stats(const struct stage *s, char *buf, size_t len);

/* Forget pulse and interrupt statistics (not positions). */
void stage_clear_stats(struct stage *s);

#endif
