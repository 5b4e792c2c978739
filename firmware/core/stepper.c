// Step generation, after GRBL's stepper.c without AMASS, overrides or lasers.
// The main loop cuts planner blocks into segments of ~10 ms at a constant
// step rate (st_prep_buffer); the step ISR runs once per step of the
// dominant axis of the block and uses Bresenham to step the others.
// Timing (board): a CTC timer whose compare is the step period, plus a
// second compare that ends the pulse; see config.h for the simavr traps.
#include <math.h>
#include <string.h>
#include "stepper.h"
#include "config.h"
#include "nuts.h"
#include "board.h"     // board_step_*, board_dir_write, board_stepper_enable, board_millis
#include "system.h"    // sys, sys_position, exec flags
#include "settings.h"  // settings
#include "planner.h"   // plan_*

#define DT_SEGMENT (1.0f / (ACCELERATION_TICKS_PER_SECOND * 60.0f)) // minutes

#define RAMP_ACCEL 0
#define RAMP_CRUISE 1
#define RAMP_DECEL 2
#define RAMP_DECEL_OVERRIDE 3

#define PREP_FLAG_RECALCULATE (1 << 0)
#define PREP_FLAG_DECEL_OVERRIDE (1 << 3)

// Blocks as the ISR sees them: step counts and directions only.
typedef struct {
  uint32_t steps[N_AXIS];
  uint32_t step_event_count;
  uint8_t direction_bits;   // already inverted for the pins
  uint8_t count_position;   // 0 for backlash take-up
  uint8_t dir_sign_bits;    // bit i: axis i moves negative (for the position)
} st_block_t;
static st_block_t st_block_buffer[SEGMENT_BUFFER_SIZE - 1];

typedef struct {
  uint16_t n_step;          // steps in this segment
  uint16_t cycles_per_tick; // timer ticks per step
  uint8_t st_block_index;
  uint8_t prescaler;        // 1: /1, 2: /8, 3: /64
} segment_t;
static segment_t segment_buffer[SEGMENT_BUFFER_SIZE];

// ISR state.
static struct {
  uint32_t counter[N_AXIS];
  uint8_t step_outbits;     // pins for the next tick (inverted)
  uint8_t pending_bits;     // steps counted in sys_position, not yet sent to the pins
  uint8_t pending_neg;      // their directions
  uint8_t pending_count;    // 1 if they were counted (not backlash)
  uint16_t step_count;
  uint8_t exec_block_index;
  st_block_t *exec_block;
  segment_t *exec_segment;
} st;

static volatile uint8_t segment_buffer_tail;
static uint8_t segment_buffer_head;
static uint8_t segment_next_head;
static volatile uint8_t busy;
static volatile uint8_t running;
static uint8_t step_port_invert_mask;
static uint8_t dir_port_invert_mask;
static uint32_t idle_since_ms;
static uint8_t idle_pending;

static plan_block_t *pl_block;
static st_block_t *st_prep_block;

typedef struct {
  uint8_t st_block_index;
  uint8_t recalculate_flag;
  float dt_remainder;
  float steps_remaining;
  float step_per_mm;
  float req_mm_increment;
  uint8_t ramp_type;
  float mm_complete;
  float current_speed;
  float maximum_speed;
  float exit_speed;
  float accelerate_until;
  float decelerate_after;
} prep_t;
static prep_t prep;

void st_generate_step_dir_invert_masks(void)
{
  step_port_invert_mask = settings.step_invert_mask;
  dir_port_invert_mask = settings.dir_invert_mask;
  board_stepper_config(settings.pulse_microseconds, step_port_invert_mask,
                       bit_istrue(settings.flags, BITFLAG_INVERT_ST_ENABLE));
}

uint8_t st_is_running(void)
{
  return running;
}

void st_wake_up(void)
{
  // The segment prep can fault (ALARM:10, drivers off) in the st_prep_buffer
  // every cycle start calls just before this: the drivers then stay off and
  // the timer stopped until the reset clears the fault.
  if (sys_fault) return;
  idle_pending = 0;
  board_stepper_enable(1);
  st.step_outbits = step_port_invert_mask;
  st.pending_bits = 0;
  if (!running) {
    running = 1;
    // First tick after ~100 us; the ISR loads the real period from the segment.
    board_step_timer_set(F_CPU / 10000, 1);
    board_step_timer_start();
  }
}

void st_go_idle(void)
{
  board_step_timer_stop();
  // A step counted for the next tick never reaches the pins: uncount it, so
  // the position stays exact after a reset or an alarm mid-move.
  if (st.pending_count) {
    for (uint8_t i = 0; i < N_AXIS; i++) {
      if (st.pending_bits & bit(i)) sys_position[i] += (st.pending_neg & bit(i)) ? 1 : -1;
    }
  }
  st.pending_bits = 0;
  st.step_outbits = step_port_invert_mask;
  running = 0;
  busy = 0;
  // Drivers go off after $1 ms unless $1=255 (held), or at once on an alarm.
  if ((settings.stepper_idle_lock_time != 0xff || sys_rt_exec_alarm) && sys.state != STATE_HOMING) {
    idle_since_ms = board_millis();
    idle_pending = 1;
    if (sys_rt_exec_alarm) {
      board_stepper_enable(0);
      idle_pending = 0;
    }
  }
}

void st_idle_poll(void)
{
  if (idle_pending && !running &&
      (uint32_t)(board_millis() - idle_since_ms) >= settings.stepper_idle_lock_time) {
    idle_pending = 0;
    board_stepper_enable(0);
  }
}

// Longest segment (min): far beyond one step at the lowest feed, only a
// guard against a zero speed.
#define MAX_SEGMENT_MIN 60.0f
// Most steps a segment counts (n_step). Accepted settings keep a segment
// near 400 (40 kHz for 10 ms, MINIMUM_FEED_RATE included).
#define SEGMENT_MAX_STEPS 65535.0f

// Step ISR, cold part: take the next segment (and block). Returns 0 when
// the ISR should end here (no segment: last pulse ending, or stopped).
// Kept out of line so the hot path of st_isr saves fewer registers.
static uint8_t __attribute__((noinline)) st_load_segment(void)
{
  if (segment_buffer_head != segment_buffer_tail) {
    st.exec_segment = &segment_buffer[segment_buffer_tail];
    board_step_timer_set(st.exec_segment->cycles_per_tick, st.exec_segment->prescaler);
    st.step_count = st.exec_segment->n_step;
    if (st.exec_block_index != st.exec_segment->st_block_index || st.exec_block == NULL) {
      st.exec_block_index = st.exec_segment->st_block_index;
      st.exec_block = &st_block_buffer[st.exec_block_index];
      st.counter[X_AXIS] = st.counter[Y_AXIS] = st.counter[Z_AXIS] = st.exec_block->step_event_count >> 1;
      // Direction changes a whole step period before the next pulse.
      board_dir_write(st.exec_block->direction_bits);
    }
    return 1;
  }
  if (st.step_outbits != step_port_invert_mask) {
    // The last pulse just started: one more empty tick lets it end.
    st.step_outbits = step_port_invert_mask;
    board_irq_disable();
    busy = 0;
    return 0;
  }
  board_irq_disable();
  st_go_idle();
  system_set_exec_state_flag(EXEC_CYCLE_STOP);
  return 0;
}

void st_isr(void)
{
  if (busy) return;   // the previous tick is still running: keep its pulse
  board_step_write(st.step_outbits);
  board_step_pulse_start();
  st.pending_bits = 0;
  busy = 1;
  board_irq_enable(); // let the pulse-end compare and the UART in

  if (st.exec_segment == NULL && !st_load_segment()) return;

  // Bresenham, unrolled: this is the hot path (one pass per step tick).
  st_block_t *b = st.exec_block;
  uint32_t ev = b->step_event_count;
  uint8_t bits = 0;
  uint32_t c;
  c = st.counter[X_AXIS] + b->steps[X_AXIS];
  if (c > ev) { bits |= bit(X_AXIS); c -= ev; }
  st.counter[X_AXIS] = c;
  c = st.counter[Y_AXIS] + b->steps[Y_AXIS];
  if (c > ev) { bits |= bit(Y_AXIS); c -= ev; }
  st.counter[Y_AXIS] = c;
  c = st.counter[Z_AXIS] + b->steps[Z_AXIS];
  if (c > ev) { bits |= bit(Z_AXIS); c -= ev; }
  st.counter[Z_AXIS] = c;
  // A limit switch or a reset taken while interrupts were open may have
  // stopped the stepper (st_go_idle): a step counted now would never reach
  // the pins, so the reported position would run one step ahead. Check and
  // count with interrupts closed, then open them again at once: the pulse-end
  // compare must not wait behind the next step tick, which outranks it.
  board_irq_disable();
  if (!running) {
    busy = 0;
    return;
  }
  if (bits && b->count_position) {
    uint8_t neg = b->dir_sign_bits;
    if (bits & bit(X_AXIS)) { if (neg & bit(X_AXIS)) sys_position[X_AXIS]--; else sys_position[X_AXIS]++; }
    if (bits & bit(Y_AXIS)) { if (neg & bit(Y_AXIS)) sys_position[Y_AXIS]--; else sys_position[Y_AXIS]++; }
    if (bits & bit(Z_AXIS)) { if (neg & bit(Z_AXIS)) sys_position[Z_AXIS]--; else sys_position[Z_AXIS]++; }
  }
  if (sys.state == STATE_HOMING) bits &= sys.homing_axis_lock;
  st.pending_bits = bits;
  st.pending_neg = b->dir_sign_bits;
  st.pending_count = b->count_position;
  st.step_outbits = bits ^ step_port_invert_mask;
  board_irq_enable();

  if (--st.step_count == 0) {
    st.exec_segment = NULL;
    uint8_t t = segment_buffer_tail + 1;
    if (t == SEGMENT_BUFFER_SIZE) t = 0;
    segment_buffer_tail = t;
  }
  board_irq_disable();
  busy = 0;
}

void st_reset(void)
{
  st_go_idle();
  idle_pending = 0;
  memset(&prep, 0, sizeof(prep));
  memset(&st, 0, sizeof(st));
  st.step_outbits = step_port_invert_mask;
  pl_block = NULL;
  segment_buffer_tail = 0;
  segment_buffer_head = 0;
  segment_next_head = 1;
  busy = 0;
  st.exec_block_index = 0xff;
  prep.st_block_index = 0;
  board_step_write(step_port_invert_mask);
  board_dir_write(dir_port_invert_mask);
}

static uint8_t st_next_block_index(uint8_t i)
{
  return (++i == SEGMENT_BUFFER_SIZE - 1) ? 0 : i;
}

void st_update_plan_block_parameters(void)
{
  if (pl_block != NULL) {
    prep.recalculate_flag |= PREP_FLAG_RECALCULATE;
    pl_block->entry_speed_sqr = prep.current_speed * prep.current_speed;
    pl_block = NULL;
  }
}

// The segment prep cannot go on with this block: stop on the fault path
// (drivers off, ALARM:10, reset to continue) rather than queue a segment
// that the step ISR would miscount, or spin here, deaf to the reset.
static void st_prep_fault(void)
{
  sys.step_control |= STEP_CONTROL_END_MOTION;
  system_fault(FAULT_INTERNAL);
}

void st_prep_buffer(void)
{
  // prep through a pointer the compiler cannot see through (the empty asm):
  // with its address known it reads and writes each float with four LDS/STS
  // (16 bytes), through the pointer with four LDD/STD (8 bytes), as fast.
  // ~125 bytes less flash.
  prep_t *p = &prep;
  __asm__("" : "+r"(p));
  if (sys.step_control & STEP_CONTROL_END_MOTION) return;

  while (segment_buffer_tail != segment_next_head) {
    if (pl_block == NULL) {
      pl_block = plan_get_current_block();
      if (pl_block == NULL) return;

      if (p->recalculate_flag & PREP_FLAG_RECALCULATE) {
        p->recalculate_flag &= ~PREP_FLAG_RECALCULATE;
      } else {
        p->st_block_index = st_next_block_index(p->st_block_index);
        st_prep_block = &st_block_buffer[p->st_block_index];
        st_prep_block->direction_bits = pl_block->direction_bits ^ dir_port_invert_mask;
        st_prep_block->dir_sign_bits = pl_block->direction_bits;
        st_prep_block->count_position = !(pl_block->condition & PL_COND_FLAG_BACKLASH);
        // Bresenham on doubled counts (as grbl without AMASS): the counter starts
        // at half an event, so a one-step block steps instead of rounding to none.
        for (uint8_t i = 0; i < N_AXIS; i++) st_prep_block->steps[i] = pl_block->steps[i] << 1;
        st_prep_block->step_event_count = pl_block->step_event_count << 1;
        // Exact for mc_line's blocks (at most MAX_BLOCK_STEPS); only a homing
        // move, which homing's own position setting follows, can be longer.
        p->steps_remaining = (float)pl_block->step_event_count;
        p->step_per_mm = p->steps_remaining / pl_block->millimeters;
        p->req_mm_increment = REQ_MM_INCREMENT_SCALAR / p->step_per_mm;
        p->dt_remainder = 0.0f;
        if ((sys.step_control & STEP_CONTROL_EXECUTE_HOLD) || (p->recalculate_flag & PREP_FLAG_DECEL_OVERRIDE)) {
          p->current_speed = p->exit_speed;
          pl_block->entry_speed_sqr = p->exit_speed * p->exit_speed;
          p->recalculate_flag &= ~PREP_FLAG_DECEL_OVERRIDE;
        } else {
          p->current_speed = sqrtf(pl_block->entry_speed_sqr);
        }
      }

      // Speed profile of this block from its current state.
      p->mm_complete = 0.0f;
      float inv_2_accel = 0.5f / pl_block->acceleration;
      if (sys.step_control & STEP_CONTROL_EXECUTE_HOLD) {
        p->ramp_type = RAMP_DECEL;
        float decel_dist = pl_block->millimeters - inv_2_accel * pl_block->entry_speed_sqr;
        if (decel_dist < 0.0f) {
          p->exit_speed = sqrtf(pl_block->entry_speed_sqr - plan_speed_sqr_change(pl_block));
        } else {
          p->mm_complete = decel_dist;
          p->exit_speed = 0.0f;
        }
      } else {
        p->ramp_type = RAMP_ACCEL;
        p->accelerate_until = pl_block->millimeters;
        float exit_speed_sqr = plan_get_exec_block_exit_speed_sqr();
        if (pl_block->condition & PL_COND_FLAG_SYSTEM_MOTION) exit_speed_sqr = 0.0f;
        p->exit_speed = sqrtf(exit_speed_sqr);
        float nominal_speed = plan_compute_profile_nominal_speed(pl_block);
        float nominal_speed_sqr = nominal_speed * nominal_speed;
        float intersect_distance = 0.5f * (pl_block->millimeters + inv_2_accel * (pl_block->entry_speed_sqr - exit_speed_sqr));
        if (pl_block->entry_speed_sqr > nominal_speed_sqr) {
          p->accelerate_until = pl_block->millimeters - inv_2_accel * (pl_block->entry_speed_sqr - nominal_speed_sqr);
          if (p->accelerate_until <= 0.0f) {
            p->ramp_type = RAMP_DECEL;
            p->exit_speed = sqrtf(pl_block->entry_speed_sqr - plan_speed_sqr_change(pl_block));
            p->recalculate_flag |= PREP_FLAG_DECEL_OVERRIDE;
          } else {
            p->decelerate_after = inv_2_accel * (nominal_speed_sqr - exit_speed_sqr);
            p->maximum_speed = nominal_speed;
            p->ramp_type = RAMP_DECEL_OVERRIDE;
          }
        } else if (intersect_distance > 0.0f) {
          if (intersect_distance < pl_block->millimeters) {
            p->decelerate_after = inv_2_accel * (nominal_speed_sqr - exit_speed_sqr);
            if (p->decelerate_after < intersect_distance) {
              p->maximum_speed = nominal_speed;
              if (pl_block->entry_speed_sqr == nominal_speed_sqr) p->ramp_type = RAMP_CRUISE;
              else p->accelerate_until -= inv_2_accel * (nominal_speed_sqr - pl_block->entry_speed_sqr);
            } else {
              p->accelerate_until = intersect_distance;
              p->decelerate_after = intersect_distance;
              p->maximum_speed = sqrtf(2.0f * pl_block->acceleration * intersect_distance + exit_speed_sqr);
            }
          } else {
            p->ramp_type = RAMP_DECEL;
          }
        } else {
          p->accelerate_until = 0.0f;
          p->maximum_speed = p->exit_speed;
        }
      }
    }

    segment_t *prep_segment = &segment_buffer[segment_buffer_head];
    prep_segment->st_block_index = p->st_block_index;

    // Advance along the profile by at least DT_SEGMENT and at least one step.
    float dt_max = DT_SEGMENT;
    float dt = 0.0f;
    float time_var = dt_max;
    float mm_var, speed_var;
    float mm_remaining = pl_block->millimeters;
    float minimum_mm = mm_remaining - p->req_mm_increment;
    if (minimum_mm < 0.0f) minimum_mm = 0.0f;

    do {
      // Speed change over time_var (unused while cruising): computed once here
      // for the three ramps that need it (one copy instead of three).
      speed_var = pl_block->acceleration * time_var;
      switch (p->ramp_type) {
        case RAMP_DECEL_OVERRIDE:
          if (p->current_speed - p->maximum_speed <= speed_var) {
            mm_remaining = p->accelerate_until;
            time_var = 2.0f * (pl_block->millimeters - mm_remaining) / (p->current_speed + p->maximum_speed);
            p->ramp_type = RAMP_CRUISE;
            p->current_speed = p->maximum_speed;
          } else {
            mm_remaining -= time_var * (p->current_speed - 0.5f * speed_var);
            p->current_speed -= speed_var;
          }
          break;
        case RAMP_ACCEL:
          mm_remaining -= time_var * (p->current_speed + 0.5f * speed_var);
          if (mm_remaining < p->accelerate_until) {
            mm_remaining = p->accelerate_until;
            time_var = 2.0f * (pl_block->millimeters - mm_remaining) / (p->current_speed + p->maximum_speed);
            p->ramp_type = (mm_remaining == p->decelerate_after) ? RAMP_DECEL : RAMP_CRUISE;
            p->current_speed = p->maximum_speed;
          } else {
            p->current_speed += speed_var;
          }
          break;
        case RAMP_CRUISE:
          mm_var = mm_remaining - p->maximum_speed * time_var;
          if (mm_var < p->decelerate_after) {
            time_var = (mm_remaining - p->decelerate_after) / p->maximum_speed;
            mm_remaining = p->decelerate_after;
            p->ramp_type = RAMP_DECEL;
          } else {
            mm_remaining = mm_var;
          }
          break;
        default: // RAMP_DECEL
          if (p->current_speed > speed_var) {
            mm_var = mm_remaining - time_var * (p->current_speed - 0.5f * speed_var);
            if (mm_var > p->mm_complete) {
              mm_remaining = mm_var;
              p->current_speed -= speed_var;
              break;
            }
          }
          time_var = 2.0f * (mm_remaining - p->mm_complete) / (p->current_speed + p->exit_speed);
          mm_remaining = p->mm_complete;
          p->current_speed = p->exit_speed;
      }
      dt += time_var;
      if (dt < dt_max) {
        time_var = dt_max - dt;
      } else if (mm_remaining > minimum_mm && dt_max < MAX_SEGMENT_MIN) {
        // Slower than one step per segment: extend it. The extension doubles:
        // on a long block at a low feed one DT_SEGMENT of travel can be below
        // float resolution of the distance left, and a fixed extension would
        // then never progress (the caller would spin on empty segments).
        time_var = dt_max;
        dt_max += time_var;
      } else {
        break;
      }
    } while (mm_remaining > p->mm_complete);

    float step_dist_remaining = p->step_per_mm * mm_remaining;
    // Steps per degree times degrees can round above the block's step count
    // (8002 / 10.0025f * 10.0025f = 8002.0006): the distance left never holds
    // more steps than are left, or a segment that moved nothing (a hold that
    // stops where a block starts) would count -1 steps.
    if (step_dist_remaining > p->steps_remaining) step_dist_remaining = p->steps_remaining;
    float n_steps_remaining = ceilf(step_dist_remaining);
    float last_n_steps_remaining = ceilf(p->steps_remaining);
    float n_step = last_n_steps_remaining - n_steps_remaining;
    if (n_step > SEGMENT_MAX_STEPS) {
      // Only with settings that $100/$110 refuse now (an EEPROM from an
      // older firmware): a step rate far above MAX_STEP_RATE_HZ.
      st_prep_fault();
      return;
    }
    prep_segment->n_step = (uint16_t)n_step;

    if (prep_segment->n_step == 0) {
      if (sys.step_control & STEP_CONTROL_EXECUTE_HOLD) {
        // Less than a step to the stop point: the hold is done here.
        sys.step_control |= STEP_CONTROL_END_MOTION;
        return;
      }
      if (mm_remaining == pl_block->millimeters && dt_max >= MAX_SEGMENT_MIN) {
        // The longest segment moved nothing: the block is too long for its
        // speed to count its distance down in a float (a $100 far below
        // MINIMUM_STEPS_PER_DEG, as an older firmware's EEPROM held before
        // settings_init raised it, and a huge target, cut by mc_line into
        // blocks far over MAX_BLOCK_DEG). At
        // cruise or decelerating no later segment would move either;
        // accelerating, each adds speed until one moves, but after
        // impractically many (the acceleration and feed floors leave this
        // only to absurdly long blocks).
        st_prep_fault();
        return;
      }
    }

    dt += p->dt_remainder;
    if (prep_segment->n_step > 0) {
      float inv_rate = dt / (last_n_steps_remaining - step_dist_remaining);  // min per step
      float cycles_f = ceilf((F_CPU * 60.0f) * inv_rate);
      if (!(cycles_f < 4.0e9f)) cycles_f = 4.0e9f;   // also catches inf/NaN
      uint32_t cycles = (uint32_t)cycles_f;
      // Never shorter than a pulse plus its low time (and never 0: see config.h).
      uint32_t min_cycles = (uint32_t)settings.pulse_microseconds * (F_CPU / 1000000UL) + STEP_PULSE_LATENCY_CYCLES + STEP_LOW_MIN_CYCLES;
      if (min_cycles < F_CPU / MAX_STEP_RATE_HZ) min_cycles = F_CPU / MAX_STEP_RATE_HZ;
      if (cycles < min_cycles) cycles = min_cycles;
      if (cycles < (1UL << 16)) {
        prep_segment->prescaler = 1;
        prep_segment->cycles_per_tick = cycles;
      } else if (cycles < (1UL << 19)) {
        prep_segment->prescaler = 2;
        prep_segment->cycles_per_tick = cycles >> 3;
      } else {
        prep_segment->prescaler = 3;
        prep_segment->cycles_per_tick = (cycles < (1UL << 22)) ? (cycles >> 6) : 0xffff;
      }
      segment_buffer_head = segment_next_head;
      if (++segment_next_head == SEGMENT_BUFFER_SIZE) segment_next_head = 0;
      p->dt_remainder = (n_steps_remaining - step_dist_remaining) * inv_rate;
    } else {
      p->dt_remainder = dt;   // no whole step yet: carry the time
    }

    pl_block->millimeters = mm_remaining;
    p->steps_remaining = n_steps_remaining;

    if (mm_remaining == p->mm_complete) {
      if (mm_remaining > 0.0f) {
        sys.step_control |= STEP_CONTROL_END_MOTION;   // hold point reached
        return;
      }
      if (pl_block->condition & PL_COND_FLAG_SYSTEM_MOTION) {
        // Homing moves end the motion: the homing loop discards the block.
        sys.step_control |= STEP_CONTROL_END_MOTION;
        return;
      }
      pl_block = NULL;
      plan_discard_current_block();
    }
  }
}

float st_get_realtime_rate(void)
{
  if (sys.state & (STATE_CYCLE | STATE_HOMING | STATE_HOLD | STATE_JOG)) return prep.current_speed;
  return 0.0f;
}
