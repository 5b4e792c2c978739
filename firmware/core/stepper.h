// Step generation: segments prepared in the main loop from planner blocks,
// stepped out by a Bresenham loop in the step timer interrupt.
#ifndef STEPPER_H
#define STEPPER_H

#include <stdint.h>

void st_reset(void);                          // main loop: stop and clear all stepper state
void st_wake_up(void);                        // main loop: drivers on, start the step timer
void st_go_idle(void);                        // any context: stop the step timer; drivers off after $1
void st_idle_poll(void);                      // main loop: disables drivers once the $1 delay has run out
void st_prep_buffer(void);                    // main loop: fill the segment buffer from the planner
void st_update_plan_block_parameters(void);   // main loop (planner): replan the block being prepared
void st_generate_step_dir_invert_masks(void); // main loop: after $2/$3/$0 change
float st_get_realtime_rate(void);             // main loop: current speed in deg/min (status report)
void st_isr(void);                            // step timer ISR: one step tick
uint8_t st_is_running(void);                  // any: 1 while the step timer runs

#endif
