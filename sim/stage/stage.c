/* stage.c: STEP/DIR integration, enable, limit switches, timing statistics.
 * The pin map is the firmware's own (firmware/avr/pins.h, included below):
 * Arduino Uno + CNC shield on an atmega328p, STEP X/Y/Z on PD2-PD4, DIR on
 * PD5-PD7, enable on PB0 (active low), limits on PB1-PB3; switches close to
 * ground, so a pressed switch reads 0. */
#include <stdio.h>
#include <string.h>
#include <math.h>

#include "avr_ioport.h"
#include "sim_interrupts.h"
#include "sim_cycle_timers.h"
#include "stage.h"
#include "pins.h" /* firmware/avr/pins.h: the one pin map */

/* A port letter from pins.h as a character ('B', 'D'). */
#define PIN_STR_(x)       #x
#define PIN_STR(x)        PIN_STR_(x)
#define PORT_CHAR(letter) (PIN_STR(letter)[0])

/* atmega328p data-space addresses: PINx, DDRx, PORTx in a row from PINB = 0x23 */
#define REG_PIN(letter)  (0x23 + 3 * (PORT_CHAR(letter) - 'B'))
#define REG_DDR(letter)  (REG_PIN(letter) + 1)
#define REG_PORT(letter) (REG_PIN(letter) + 2)

#define STEP_BIT0       X_STEP_BIT
#define DIR_BIT0        X_DIR_BIT
#define LIMIT_BIT0      X_LIMIT_BIT
#define REG_STEP_DDR    REG_DDR(STEP_PORT_LETTER)
#define REG_DIR_PORT    REG_PORT(DIR_PORT_LETTER)
#define REG_ENABLE_DDR  REG_DDR(ENABLE_PORT_LETTER)
#define REG_ENABLE_PORT REG_PORT(ENABLE_PORT_LETTER)
#define REG_LIMIT_PIN   REG_PIN(LIMIT_PORT_LETTER)

/* atmega328p timer registers (data space) for the CTC-compare-0 check */
static const struct {
    uint8_t tccra, tccrb, ocra_lo, ocra_hi, timsk; /* ocra_hi 0: 8-bit timer */
} timers[3] = {
    {0x44, 0x45, 0x47, 0x00, 0x6e}, /* timer0 */
    {0x80, 0x81, 0x88, 0x89, 0x6f}, /* timer1 */
    {0xb0, 0xb1, 0xb3, 0x00, 0x70}, /* timer2 */
};

void stage_check_timer_traps(struct stage *s)
{
    const uint8_t *d = s->avr->data;

    for (int t = 0; t < 3; t++) {
        uint8_t a = d[timers[t].tccra], b = d[timers[t].tccrb];
        int running = (b & 7) != 0;
        /* CTC on OCRnA: WGM = 2 (timers 0/2) or 4 (timer1) */
        int wgm = t == 1 ? (a & 3) | ((b >> 1) & 0x0c) : (a & 3) | ((b >> 1) & 4);
        int ctc = wgm == (t == 1 ? 4 : 2);
        unsigned ocr = d[timers[t].ocra_lo] | (timers[t].ocra_hi ? d[timers[t].ocra_hi] << 8 : 0);
        int irq = d[timers[t].timsk] & 2; /* OCIEnA */
        if (running && ctc && irq && ocr == 0 && !(s->trap_warned & (1 << t))) {
            s->trap_warned |= 1 << t;
            fprintf(stderr,
                    "stagesim: warning: timer%d in CTC mode with OCR%dA = 0 at cycle %llu: "
                    "simavr 1.6 never fires this compare (silicon does)\n",
                    t, t, (unsigned long long)s->avr->cycle);
        }
    }
}

int stage_enabled(const struct stage *s)
{
    const uint8_t *d = s->avr->data;
    return (d[REG_ENABLE_DDR] & (1 << ENABLE_BIT)) && !(d[REG_ENABLE_PORT] & (1 << ENABLE_BIT));
}

double stage_angle(const struct stage *s, int axis)
{
    const struct stage_axis *a = &s->axis[axis];
    return (double)a->steps / a->steps_per_deg;
}

static void min_update(uint64_t *slot, uint64_t v)
{
    if (*slot == 0 || v < *slot) *slot = v;
}

/* Drive one limit input. The level is also declared to simavr as the pin's
 * external value: simavr 1.6 otherwise raises an input pin with its pull-up
 * on to 1 whenever the firmware writes the port register (PORTB also holds
 * the driver enable), a glitch on a pressed switch that silicon never sees. */
static void limit_pin(struct stage *s, int axis, int level)
{
    avr_ioport_external_t ext = {0};
    uint8_t bit = (uint8_t)(1u << (LIMIT_BIT0 + axis));

    s->limit_levels = (uint8_t)(level ? s->limit_levels | bit : s->limit_levels & ~bit);
    ext.name = PORT_CHAR(LIMIT_PORT_LETTER);
    ext.mask = LIMIT_MASK;
    ext.value = s->limit_levels;
    avr_ioctl(s->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(PORT_CHAR(LIMIT_PORT_LETTER)), &ext);
    avr_raise_irq(s->limit_irq[axis], (uint32_t)level);
}

static void limit_drive(struct stage *s, struct stage_axis *a, int level)
{
    if (a->limit_level_driven != level) {
        a->limit_level_driven = level;
        limit_pin(s, a->index, level);
    }
}

static avr_cycle_count_t bounce_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
    struct stage_axis *a = param;
    struct stage *s = a->stage;
    int settled = !a->limit_active;

    (void)avr;
    if (a->bounce_left > 0) a->bounce_left--;
    /* odd counts left: the contact is open again for a moment */
    limit_drive(s, a, (a->bounce_left & 1) ? !settled : settled);
    return a->bounce_left ? when + s->bounce_cycles : 0;
}

/* Switch model: pressed once the axis is at or beyond the switch position in
 * the switch's direction (and within limit_width past it, if set); once
 * pressed it releases only after backing off by limit_hyst. */
static void limit_update(struct stage *s, struct stage_axis *a)
{
    double past, lo, hi;
    int active;

    if (!a->limit_enabled) return;
    past = a->limit_dir * (stage_angle(s, a->index) - a->limit_deg);
    lo = a->limit_active ? -s->limit_hyst : 0.0;
    hi = s->limit_width > 0 ? s->limit_width + (a->limit_active ? s->limit_hyst : 0.0) : INFINITY;
    active = past >= lo - 1e-9 && past <= hi + 1e-9;
    if (active && !a->limit_active) a->limit_hits++;
    if (active != a->limit_active && s->bounce_count > 0) {
        /* a real contact chatters: the pin settles after a few bounces */
        a->limit_active = active;
        a->bounce_left = 2 * s->bounce_count;
        avr_cycle_timer_cancel(s->avr, bounce_timer, a);
        limit_drive(s, a, !active);
        avr_cycle_timer_register(s->avr, s->bounce_cycles, bounce_timer, a);
        return;
    }
    a->limit_active = active;
    if (!a->bounce_left) limit_drive(s, a, !active);
}

void stage_sync_limits(struct stage *s)
{
    for (int i = 0; i < STAGE_AXES; i++) {
        struct stage_axis *a = &s->axis[i];
        if (a->bounce_left && !avr_cycle_timer_status(s->avr, bounce_timer, a)) {
            /* a reset dropped the bounce timer: the contact has settled */
            a->bounce_left = 0;
            a->limit_level_driven = !a->limit_active;
        }
        int level = a->limit_level_driven >= 0 ? a->limit_level_driven
                                               : (a->limit_enabled ? !a->limit_active : 1);
        int bit = (s->avr->data[REG_LIMIT_PIN] >> (LIMIT_BIT0 + i)) & 1;
        if (bit != level || a->limit_level_driven != level) {
            a->limit_level_driven = level;
            /* a reset clears the pin register but not the IRQ's last
			 * value, and simavr drops a raise that repeats the value */
            s->limit_irq[i]->value = (uint32_t)!level;
            limit_pin(s, i, level);
        }
    }
}

static void step_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    struct stage_axis *a = param;
    struct stage *s = a->stage;
    avr_t *avr = s->avr;
    uint64_t now = avr->cycle;
    int inv = (s->step_invert_mask >> a->index) & 1;
    int old = (int)(irq->value & 1) ^ inv;
    int v = (int)(value & 1) ^ inv;
    int dir;

    if (v == old) return;
    if (!v) { /* trailing edge */
        if (a->last_rise) min_update(&a->min_high, now - a->last_rise);
        a->last_fall = now;
        return;
    }
    if (a->last_fall) min_update(&a->min_low, now - a->last_fall);
    if (a->last_rise) min_update(&a->min_period, now - a->last_rise);
    a->last_rise = now;

    dir = (avr->data[REG_DIR_PORT] >> (DIR_BIT0 + a->index)) & 1;
    if (dir != a->dir_level) {
        /* DIR changes in this very write: no setup time at all */
        a->dir_violations++;
        a->min_dir_setup = 1;
    } else if (a->dir_pending) {
        min_update(&a->min_dir_setup, now - a->dir_change);
    }
    a->dir_pending = 0;

    if (!(avr->data[REG_STEP_DDR] & (1 << (STEP_BIT0 + a->index))) || !stage_enabled(s)) {
        a->ignored++;
        return;
    }
    dir ^= (s->dir_invert_mask >> a->index) & 1;
    a->steps += dir ? -1 : 1; /* grbl convention: DIR high = negative */
    a->pulses++;
    limit_update(s, a);
}

static void dir_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    struct stage_axis *a = param;
    struct stage *s = a->stage;
    int v = (int)(value & 1);

    (void)irq;
    if (v == a->dir_level) return;
    a->dir_level = v;
    a->dir_pending = 1;
    a->dir_change = s->avr->cycle;
    /* the driver samples DIR at the rising STEP edge; changing it while STEP
	 * is still high is harmless for A4988/DRV8825 but worth counting when it
	 * happens before the minimum hold time */
    if (a->last_rise && a->last_fall < a->last_rise && s->avr->cycle - a->last_rise < 4)
        a->dir_violations++;
}

struct vec_ctx {
    struct stage *stage;
    int vector;
};
static struct vec_ctx vec_ctx[STAGE_VECTORS];

static void running_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    struct vec_ctx *c = param;
    struct stage_vector *v = &c->stage->vec[c->vector];
    uint64_t now = c->stage->avr->cycle;

    (void)irq;
    if (value) {
        v->entered = now;
        v->count++;
    } else if (v->entered) {
        uint64_t d = now - v->entered;
        v->total_cycles += d;
        if (d > v->max_cycles) v->max_cycles = d;
        v->entered = 0;
    }
}

int stage_attach(struct stage *s, avr_t *avr, char *err)
{
    s->avr = avr;
    for (int i = 0; i < STAGE_AXES; i++) {
        struct stage_axis *a = &s->axis[i];
        avr_irq_t *step =
            avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(PORT_CHAR(STEP_PORT_LETTER)), STEP_BIT0 + i);
        avr_irq_t *dir =
            avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(PORT_CHAR(DIR_PORT_LETTER)), DIR_BIT0 + i);
        s->limit_irq[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(PORT_CHAR(LIMIT_PORT_LETTER)),
                                        LIMIT_BIT0 + i);
        if (!step || !dir || !s->limit_irq[i]) {
            snprintf(err, ERR_LEN, "avr_io_getirq: no port B/D pins on %s", avr->mmcu);
            return -1;
        }
        a->stage = s;
        a->index = i;
        a->limit_level_driven = -1;
        avr_irq_register_notify(step, step_hook, a);
        avr_irq_register_notify(dir, dir_hook, a);
        limit_update(s, a);
    }
    for (int v = 1; v < STAGE_VECTORS; v++) {
        avr_irq_t *irq = avr_get_interrupt_irq(avr, (uint8_t)v);
        if (!irq) continue;
        vec_ctx[v].stage = s;
        vec_ctx[v].vector = v;
        avr_irq_register_notify(irq + AVR_INT_IRQ_RUNNING, running_hook, &vec_ctx[v]);
    }
    stage_sync_limits(s);
    return 0;
}

void stage_clear_stats(struct stage *s)
{
    for (int i = 0; i < STAGE_AXES; i++) {
        struct stage_axis *a = &s->axis[i];
        a->pulses = a->ignored = a->dir_violations = a->limit_hits = 0;
        a->min_high = a->min_low = a->min_period = a->min_dir_setup = 0;
        a->last_rise = a->last_fall = 0;
        a->dir_pending = 0;
    }
    s->cli_max = 0;
    s->cli_max_pc = 0;
    for (int v = 0; v < STAGE_VECTORS; v++) {
        uint64_t entered = s->vec[v].entered;
        memset(&s->vec[v], 0, sizeof(s->vec[v]));
        s->vec[v].entered = entered;
    }
}

size_t stage_format_state(const struct stage *s, char *buf, size_t len)
{
    int n = snprintf(buf, len,
                     "{\"x\": %.6f, \"y\": %.6f, \"z\": %.6f, \"steps\": [%ld, %ld, %ld], "
                     "\"enabled\": %s, \"cycle\": %llu, \"limits\": [%d, %d, %d]}\n",
                     stage_angle(s, 0), stage_angle(s, 1), stage_angle(s, 2), s->axis[0].steps,
                     s->axis[1].steps, s->axis[2].steps, stage_enabled(s) ? "true" : "false",
                     (unsigned long long)s->avr->cycle, s->axis[0].limit_active,
                     s->axis[1].limit_active, s->axis[2].limit_active);
    return n < 0 ? 0 : ((size_t)n >= len ? len - 1 : (size_t)n);
}

size_t stage_format_stats(const struct stage *s, char *buf, size_t len)
{
    size_t off = 0;
    int n;

#define OUT(...)                                         \
    do {                                                 \
        n = snprintf(buf + off, len - off, __VA_ARGS__); \
        if (n < 0 || (size_t)n >= len - off) return off; \
        off += (size_t)n;                                \
    } while (0)

    OUT("{\"cycle\": %llu, \"frequency\": %u, \"axes\": [", (unsigned long long)s->avr->cycle,
        s->avr->frequency);
    for (int i = 0; i < STAGE_AXES; i++) {
        const struct stage_axis *a = &s->axis[i];
        OUT("%s{\"steps\": %ld, \"pulses\": %llu, \"ignored\": %llu, "
            "\"min_high\": %llu, \"min_low\": %llu, \"min_period\": %llu, "
            "\"min_dir_setup\": %llu, \"dir_violations\": %llu, \"limit_hits\": %llu}",
            i ? ", " : "", a->steps, (unsigned long long)a->pulses, (unsigned long long)a->ignored,
            (unsigned long long)a->min_high, (unsigned long long)a->min_low,
            (unsigned long long)a->min_period, (unsigned long long)a->min_dir_setup,
            (unsigned long long)a->dir_violations, (unsigned long long)a->limit_hits);
    }
    OUT("], \"max_irq_off_cycles\": %llu, \"max_irq_off_pc\": \"0x%04x\", \"vectors\": {",
        (unsigned long long)s->cli_max, (unsigned)s->cli_max_pc);
    int first = 1;
    for (int v = 1; v < STAGE_VECTORS; v++) {
        const struct stage_vector *sv = &s->vec[v];
        if (!sv->count) continue;
        OUT("%s\"%d\": {\"count\": %llu, \"max_cycles\": %llu, \"total_cycles\": %llu}",
            first ? "" : ", ", v, (unsigned long long)sv->count, (unsigned long long)sv->max_cycles,
            (unsigned long long)sv->total_cycles);
        first = 0;
    }
    OUT("}}\n");
#undef OUT
    return off;
}
