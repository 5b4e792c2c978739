// Motion commands: the entry points from G-code into the planner.
#ifndef MOTION_H
#define MOTION_H

#include <stdint.h>
#include "planner.h"

void mc_line(const float *target, plan_line_data_t *pl_data); // main loop: queue a line to target (deg, machine); waits while the buffer is full
void mc_dwell(float seconds);     // main loop: G4, waits for the buffer to empty first
void mc_reset(void);              // any context (0x18 from the UART ISR): stop at once, alarm if moving

#endif
