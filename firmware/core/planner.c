// Look-ahead planner: a ring of linear moves with trapezoidal speed profiles.
// The algorithm is GRBL's: junction deviation bounds the speed at each
// corner, a reverse pass lowers entry speeds so every block can stop in time,
// a forward pass limits them to what acceleration can reach.
// Backlash (not in GRBL): when an axis reverses, a take-up block that moves
// only the reversing axes by their $14x is queued first; its steps are not
// counted in the machine position.
#include <string.h>
#include <math.h>
#include "planner.h"
#include "nuts.h"
#include "settings.h"  // settings
#include "system.h"    // sys_position
#include "stepper.h"   // st_update_plan_block_parameters

#define SOME_LARGE_VALUE 1.0e38f

static plan_block_t block_buffer[BLOCK_BUFFER_SIZE];
static uint8_t block_buffer_tail;    // block being executed
static uint8_t block_buffer_head;    // next free block
static uint8_t next_buffer_head;
static uint8_t block_buffer_planned; // first block whose speed may still change

static struct {
  int32_t position[N_AXIS];          // planner position in steps (end of the last block)
  float previous_unit_vec[N_AXIS];
  float previous_nominal_speed;
  uint8_t last_dir_bits;             // direction each axis last moved (for backlash)
} pl;

// Out of line: called from seven places, where LTO's inlined copies cost
// more flash than the calls.
static uint8_t __attribute__((noinline)) plan_next_block_index(uint8_t i)
{
  return (++i == BLOCK_BUFFER_SIZE) ? 0 : i;
}

static uint8_t plan_prev_block_index(uint8_t i)
{
  return (i == 0 ? BLOCK_BUFFER_SIZE : i) - 1;
}

void plan_init(void)
{
  memset(&pl, 0, sizeof(pl));
  plan_reset();
}

void plan_reset(void)
{
  // The direction each motor last turned survives a reset (backlash state).
  uint8_t last_dir = pl.last_dir_bits;
  memset(&pl, 0, sizeof(pl));
  pl.last_dir_bits = last_dir;
  block_buffer_tail = 0;
  block_buffer_head = 0;
  next_buffer_head = 1;
  block_buffer_planned = 0;
}

// Out of line: the two planner passes and the segment prep's deceleration
// had five copies of it.
float __attribute__((noinline)) plan_speed_sqr_change(const plan_block_t *block)
{
  return 2 * block->acceleration * block->millimeters;
}

static void planner_recalculate(void)
{
  uint8_t block_index = plan_prev_block_index(block_buffer_head);
  if (block_index == block_buffer_planned) return;

  float entry_speed_sqr;
  plan_block_t *next;
  plan_block_t *current = &block_buffer[block_index];
  // The last block must be able to stop.
  entry_speed_sqr = plan_speed_sqr_change(current);
  current->entry_speed_sqr = min(current->max_entry_speed_sqr, entry_speed_sqr);

  block_index = plan_prev_block_index(block_index);
  if (block_index == block_buffer_planned) {
    if (block_index == block_buffer_tail) st_update_plan_block_parameters();
  } else {
    while (block_index != block_buffer_planned) {   // reverse pass
      next = current;
      current = &block_buffer[block_index];
      block_index = plan_prev_block_index(block_index);
      if (block_index == block_buffer_tail) st_update_plan_block_parameters();
      if (current->entry_speed_sqr != current->max_entry_speed_sqr) {
        entry_speed_sqr = next->entry_speed_sqr + plan_speed_sqr_change(current);
        current->entry_speed_sqr = min(entry_speed_sqr, current->max_entry_speed_sqr);
      }
    }
  }

  next = &block_buffer[block_buffer_planned];       // forward pass
  block_index = plan_next_block_index(block_buffer_planned);
  while (block_index != block_buffer_head) {
    current = next;
    next = &block_buffer[block_index];
    if (current->entry_speed_sqr < next->entry_speed_sqr) {
      entry_speed_sqr = current->entry_speed_sqr + plan_speed_sqr_change(current);
      if (entry_speed_sqr < next->entry_speed_sqr) {
        next->entry_speed_sqr = entry_speed_sqr;
        block_buffer_planned = block_index;
      }
    }
    if (next->entry_speed_sqr == next->max_entry_speed_sqr) block_buffer_planned = block_index;
    block_index = plan_next_block_index(block_index);
  }
}

plan_block_t *plan_get_current_block(void)
{
  if (block_buffer_head == block_buffer_tail) return NULL;
  return &block_buffer[block_buffer_tail];
}

plan_block_t *plan_peek_block(uint8_t n)
{
  uint8_t i = block_buffer_tail;
  while (n--) {
    if (i == block_buffer_head) return NULL;
    i = plan_next_block_index(i);
  }
  return i == block_buffer_head ? NULL : &block_buffer[i];
}

void plan_discard_current_block(void)
{
  if (block_buffer_head != block_buffer_tail) {
    uint8_t block_index = plan_next_block_index(block_buffer_tail);
    if (block_buffer_tail == block_buffer_planned) block_buffer_planned = block_index;
    block_buffer_tail = block_index;
  }
}

float plan_get_exec_block_exit_speed_sqr(void)
{
  uint8_t block_index = plan_next_block_index(block_buffer_tail);
  if (block_index == block_buffer_head) return 0.0f;
  return block_buffer[block_index].entry_speed_sqr;
}

uint8_t plan_check_full_buffer(void)
{
  return block_buffer_tail == next_buffer_head;
}

uint8_t plan_get_block_buffer_available(void)
{
  if (block_buffer_head >= block_buffer_tail)
    return (BLOCK_BUFFER_SIZE - 1) - (block_buffer_head - block_buffer_tail);
  return block_buffer_tail - block_buffer_head - 1;
}

float plan_compute_profile_nominal_speed(const plan_block_t *block)
{
  // As GRBL: rapids scale by the rapid override, feeds by the feed override
  // but never past the rapid rate (a rapid's programmed rate is its rapid
  // rate, and its override at most 100 %); jogs and homing run as asked.
  uint8_t ovr = 100;
  if (!(block->condition & PL_COND_FLAG_NO_FEED_OVERRIDE))
    ovr = (block->condition & PL_COND_FLAG_RAPID_MOTION) ? sys.r_override : sys.f_override;
  float nominal_speed = block->programmed_rate * (0.01f * ovr);
  if (nominal_speed > block->rapid_rate) nominal_speed = block->rapid_rate;
  return nominal_speed > MINIMUM_FEED_RATE ? nominal_speed : MINIMUM_FEED_RATE;
}

// Entry speed limit from the junction and the nominal speeds on both sides.
// Out of line: its two callers each had a copy.
static void __attribute__((noinline)) plan_compute_profile_parameters(plan_block_t *block, float nominal_speed, float prev_nominal_speed)
{
  block->max_entry_speed_sqr = (nominal_speed > prev_nominal_speed) ? prev_nominal_speed * prev_nominal_speed
                                                                    : nominal_speed * nominal_speed;
  if (block->max_entry_speed_sqr > block->max_junction_speed_sqr) block->max_entry_speed_sqr = block->max_junction_speed_sqr;
}

void plan_update_velocity_profile_parameters(void)
{
  uint8_t block_index = block_buffer_tail;
  float prev_nominal_speed = SOME_LARGE_VALUE;   // the executing block keeps its own entry speed
  while (block_index != block_buffer_head) {
    plan_block_t *block = &block_buffer[block_index];
    float nominal_speed = plan_compute_profile_nominal_speed(block);
    plan_compute_profile_parameters(block, nominal_speed, prev_nominal_speed);
    prev_nominal_speed = (block->condition & PL_COND_FLAG_SYSTEM_MOTION) ? 0.0f : nominal_speed;
    block_index = plan_next_block_index(block_index);
  }
  pl.previous_nominal_speed = prev_nominal_speed;
}

void plan_sync_position(void)
{
  system_get_position(pl.position);
}

void plan_set_last_direction(uint8_t axes, uint8_t negative_bits)
{
  pl.last_dir_bits = (pl.last_dir_bits & ~axes) | (negative_bits & axes);
}

void plan_get_position(float *position)
{
  for (uint8_t i = 0; i < N_AXIS; i++) position[i] = pl.position[i] / settings.steps_per_deg[i];
}

void plan_cycle_reinitialize(void)
{
  st_update_plan_block_parameters();
  block_buffer_planned = block_buffer_tail;
  planner_recalculate();
}

static float convert_delta_vector_to_unit_vector(float *vector)
{
  float magnitude = 0.0f;
  for (uint8_t i = 0; i < N_AXIS; i++) magnitude += vector[i] * vector[i];
  magnitude = sqrtf(magnitude);
  float inv = 1.0f / magnitude;
  for (uint8_t i = 0; i < N_AXIS; i++) vector[i] *= inv;
  return magnitude;
}

// The largest value along unit_vec that no axis' own limit is exceeded by.
static float limit_value_by_axis_maximum(const float *max_value, const float *unit_vec)
{
  float limit = SOME_LARGE_VALUE;
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (unit_vec[i] != 0) limit = min(limit, fabsf(max_value[i] / unit_vec[i]));
  }
  return limit;
}

static uint8_t plan_backlash_axes(const int32_t *target_steps)
{
  uint8_t axes = 0;
  for (uint8_t i = 0; i < N_AXIS; i++) {
    if (settings.backlash[i] <= 0.0f || target_steps[i] == pl.position[i]) continue;
    uint8_t neg = target_steps[i] < pl.position[i];
    if (neg != ((pl.last_dir_bits >> i) & 1)) axes |= bit(i);
  }
  return axes;
}

static void plan_target_steps(const float *target, int32_t *target_steps)
{
  for (uint8_t i = 0; i < N_AXIS; i++) target_steps[i] = nuts_lround(target[i] * settings.steps_per_deg[i]);
}

uint8_t plan_backlash_blocks_needed(const float *target)
{
  int32_t target_steps[N_AXIS];
  plan_target_steps(target, target_steps);
  return plan_backlash_axes(target_steps) ? 2 : 1;
}

// Fill block at the head from step deltas and queue it. Returns PLAN_OK or PLAN_EMPTY_BLOCK.
static uint8_t plan_queue_block(const int32_t *delta_steps, float feed_rate, uint8_t condition)
{
  plan_block_t *block = &block_buffer[block_buffer_head];
  memset(block, 0, sizeof(plan_block_t));
  block->condition = condition;

  float unit_vec[N_AXIS];
  for (uint8_t i = 0; i < N_AXIS; i++) {
    int32_t d = delta_steps[i];
    block->steps[i] = (uint32_t)(d < 0 ? -d : d);
    block->step_event_count = max(block->step_event_count, block->steps[i]);
    unit_vec[i] = d / settings.steps_per_deg[i];
    if (d < 0) block->direction_bits |= bit(i);
  }
  if (block->step_event_count == 0) return PLAN_EMPTY_BLOCK;

  block->millimeters = convert_delta_vector_to_unit_vector(unit_vec);
  float accel[N_AXIS];
  // deg/s^2 -> deg/min^2, raised to the floor as slow feeds are (config.h: a
  // lower one would stall the segment prep; settings_init raises one left in
  // EEPROM by an older firmware, this the float steps under that $120 lets through).
  for (uint8_t i = 0; i < N_AXIS; i++) accel[i] = max(settings.acceleration[i], MINIMUM_ACCELERATION) * 3600.0f;
  block->acceleration = limit_value_by_axis_maximum(accel, unit_vec);
  block->rapid_rate = limit_value_by_axis_maximum(settings.max_rate, unit_vec);
  block->programmed_rate = (condition & PL_COND_FLAG_RAPID_MOTION) ? block->rapid_rate : feed_rate;
  float nominal_speed = plan_compute_profile_nominal_speed(block);

  if (block_buffer_head == block_buffer_tail || (condition & PL_COND_FLAG_SYSTEM_MOTION)) {
    block->entry_speed_sqr = 0.0f;
    block->max_junction_speed_sqr = 0.0f;
  } else {
    float junction_unit_vec[N_AXIS];
    float junction_cos_theta = 0.0f;
    for (uint8_t i = 0; i < N_AXIS; i++) {
      junction_cos_theta -= pl.previous_unit_vec[i] * unit_vec[i];
      junction_unit_vec[i] = unit_vec[i] - pl.previous_unit_vec[i];
    }
    if (junction_cos_theta > 0.999999f) {
      block->max_junction_speed_sqr = MINIMUM_JUNCTION_SPEED * MINIMUM_JUNCTION_SPEED;
    } else if (junction_cos_theta < -0.999999f) {
      block->max_junction_speed_sqr = SOME_LARGE_VALUE;
    } else {
      convert_delta_vector_to_unit_vector(junction_unit_vec);
      float junction_acceleration = limit_value_by_axis_maximum(accel, junction_unit_vec);
      float sin_theta_d2 = sqrtf(0.5f * (1.0f - junction_cos_theta));
      block->max_junction_speed_sqr = max(MINIMUM_JUNCTION_SPEED * MINIMUM_JUNCTION_SPEED,
          (junction_acceleration * settings.junction_deviation * sin_theta_d2) / (1.0f - sin_theta_d2));
    }
  }

  plan_compute_profile_parameters(block, nominal_speed, pl.previous_nominal_speed);
  if (condition & PL_COND_FLAG_SYSTEM_MOTION) {
    pl.previous_nominal_speed = 0.0f;   // homing moves start and end at rest
    memset(pl.previous_unit_vec, 0, sizeof(pl.previous_unit_vec));
  } else {
    pl.previous_nominal_speed = nominal_speed;
    memcpy(pl.previous_unit_vec, unit_vec, sizeof(unit_vec));
  }

  block_buffer_head = next_buffer_head;
  next_buffer_head = plan_next_block_index(block_buffer_head);
  planner_recalculate();
  return PLAN_OK;
}

uint8_t plan_buffer_line(const float *target, const plan_line_data_t *pl_data)
{
  int32_t target_steps[N_AXIS];
  int32_t position[N_AXIS];
  int32_t delta[N_AXIS];
  plan_target_steps(target, target_steps);

  if (pl_data->condition & PL_COND_FLAG_SYSTEM_MOTION) {
    // Homing moves relative to where the motors are now.
    system_get_position(position);
    for (uint8_t i = 0; i < N_AXIS; i++) delta[i] = target_steps[i] - position[i];
    return plan_queue_block(delta, pl_data->feed_rate, pl_data->condition);
  }

  uint8_t bl_axes = plan_backlash_axes(target_steps);
  if (bl_axes) {
    for (uint8_t i = 0; i < N_AXIS; i++) {
      delta[i] = 0;
      if (bl_axes & bit(i)) {
        int32_t n = nuts_lround(settings.backlash[i] * settings.steps_per_deg[i]);
        delta[i] = (target_steps[i] < pl.position[i]) ? -n : n;
      }
    }
    plan_queue_block(delta, settings.max_rate[0] + settings.max_rate[1] + settings.max_rate[2],
                     PL_COND_FLAG_BACKLASH | PL_COND_FLAG_RAPID_MOTION |
                     (pl_data->condition & (PL_COND_FLAG_JOG | PL_COND_FLAG_NO_FEED_OVERRIDE)));
  }
  for (uint8_t i = 0; i < N_AXIS; i++) {
    delta[i] = target_steps[i] - pl.position[i];
    if (delta[i] > 0) pl.last_dir_bits &= ~bit(i);
    else if (delta[i] < 0) pl.last_dir_bits |= bit(i);
  }
  uint8_t r = plan_queue_block(delta, pl_data->feed_rate, pl_data->condition);
  memcpy(pl.position, target_steps, sizeof(target_steps));
  return r;
}
