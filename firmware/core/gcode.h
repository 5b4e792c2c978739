// G-code parser and executor (degrees; the subset a rotation stage needs).
#ifndef GCODE_H
#define GCODE_H

#include <stdint.h>
#include "config.h"

#define MOTION_MODE_SEEK 0
#define MOTION_MODE_LINEAR 1
#define MOTION_MODE_NONE 80

#define PROGRAM_FLOW_RUNNING 0
#define PROGRAM_FLOW_PAUSED 1      // M0 (reported as M0 in $G)
#define PROGRAM_FLOW_COMPLETED_M2 2
#define PROGRAM_FLOW_COMPLETED_M30 30

typedef struct {
  uint8_t motion;        // MOTION_MODE_*
  uint8_t distance;      // 0 = G90, 1 = G91
  uint8_t coord_select;  // 0..5 = G54..G59
  uint8_t program_flow;  // PROGRAM_FLOW_*
} gc_modal_t;

typedef struct {
  gc_modal_t modal;
  float feed_rate;               // deg/min
  int32_t line_number;
  float position[N_AXIS];        // where the parser thinks the machine is (deg, machine frame)
  float coord_system[N_AXIS];    // active G54..G59 offset (deg)
  float coord_offset[N_AXIS];    // G92 offset (deg)
} parser_state_t;

extern parser_state_t gc_state;

void gc_init(void);                           // main loop, after reset: default modes, G54 loaded
void gc_sync_position(void);                  // main loop: parser position = machine position
uint8_t gc_execute_line(char *line, uint8_t jog); // main loop: parse and run one cleaned line; status code

#endif
