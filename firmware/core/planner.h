// Look-ahead planner: a ring of linear moves with trapezoidal speed profiles.
// Lengths are degrees (Euclidean over the axes, as GRBL over mm), speeds deg/min.
#ifndef PLANNER_H
#define PLANNER_H

#include <stdint.h>
#include "config.h"

#define PLAN_OK 1
#define PLAN_EMPTY_BLOCK 0

// plan_line_data_t.condition / plan_block_t.condition
#define PL_COND_FLAG_RAPID_MOTION (1 << 0)
#define PL_COND_FLAG_SYSTEM_MOTION (1 << 1)  // homing: not part of the program position
#define PL_COND_FLAG_BACKLASH (1 << 2)       // backlash take-up: steps not counted in the position
#define PL_COND_FLAG_JOG (1 << 3)
#define PL_COND_FLAG_NO_FEED_OVERRIDE (1 << 4) // jog and homing run at the rate asked

typedef struct {
  uint32_t steps[N_AXIS];      // steps per axis, absolute
  uint32_t step_event_count;   // steps of the dominant axis
  uint8_t direction_bits;      // bit i set: axis i moves negative
  uint8_t condition;           // PL_COND_FLAG_*
  float entry_speed_sqr;       // (deg/min)^2, planned
  float max_entry_speed_sqr;   // (deg/min)^2, junction and nominal limit
  float max_junction_speed_sqr;
  float programmed_rate;       // deg/min: the F word, or the rapid rate (before overrides)
  float rapid_rate;            // deg/min: the axes' $11x limit along this move
  float acceleration;          // deg/min^2 along the move
  float millimeters;           // degrees left in this move (the name is GRBL's)
} plan_block_t;

typedef struct {
  float feed_rate;             // deg/min
  uint8_t condition;           // PL_COND_FLAG_*
} plan_line_data_t;

void plan_init(void);                               // main, at power-up: as plan_reset, and forget the backlash state
void plan_reset(void);                              // main loop: empty the buffer and state (backlash state kept)
uint8_t plan_buffer_line(const float *target, const plan_line_data_t *pl_data); // main loop: queue a move to target (deg); PLAN_OK or PLAN_EMPTY_BLOCK
plan_block_t *plan_get_current_block(void);          // main loop / prep: block being executed, or NULL
plan_block_t *plan_peek_block(uint8_t n);            // tests: the n-th queued block after the current one, or NULL
void plan_discard_current_block(void);              // prep (main loop): block finished
float plan_get_exec_block_exit_speed_sqr(void);     // prep: entry speed of the next block
uint8_t plan_check_full_buffer(void);               // main loop: 1 when no block is free
uint8_t plan_get_block_buffer_available(void);      // main loop: free blocks
void plan_sync_position(void);                      // main loop: planner position = machine position
void plan_get_position(float *position);            // main loop: end of the last queued move (deg)
void plan_set_last_direction(uint8_t axes, uint8_t negative_bits); // main loop (homing): direction the axes last turned, for backlash
void plan_cycle_reinitialize(void);                 // main loop: after a hold, replan from zero speed
uint8_t plan_backlash_blocks_needed(const float *target); // main loop: free blocks a move to target needs (1 or 2)
float plan_speed_sqr_change(const plan_block_t *block); // planner, prep: 2 a d, the change in speed^2 over the degrees left in block
float plan_compute_profile_nominal_speed(const plan_block_t *block); // prep: deg/min, overrides applied
void plan_update_velocity_profile_parameters(void); // main loop: an override changed: new speed limits for every queued block

#endif
