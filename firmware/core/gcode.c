// G-code parser and executor, after GRBL's gcode.c: parse every word of the
// line first, check the whole line, then act. Units are degrees: G21 is
// accepted (the stage's only unit), G20 is refused.
#include <string.h>
#include <math.h>
#include "gcode.h"
#include "codes.h"
#include "nuts.h"
#include "system.h"    // sys
#include "settings.h"  // coordinate data, settings
#include "planner.h"   // plan_line_data_t, plan_sync_position
#include "motion.h"    // mc_line, mc_dwell
#include "protocol.h"  // protocol_buffer_synchronize
#include "report.h"    // report_feedback_message
#include "stepper.h"   // st_prep_buffer, st_wake_up

parser_state_t gc_state;

// Non-modal actions (group 0)
#define NON_MODAL_NONE 0
#define NON_MODAL_DWELL 4
#define NON_MODAL_SET_COORDINATE_DATA 10
#define NON_MODAL_GO_HOME_0 28
#define NON_MODAL_SET_HOME_0 38
#define NON_MODAL_GO_HOME_1 30
#define NON_MODAL_SET_HOME_1 40
#define NON_MODAL_ABSOLUTE_OVERRIDE 53
#define NON_MODAL_SET_COORDINATE_OFFSET 92
#define NON_MODAL_RESET_COORDINATE_OFFSET 102

// Modal groups, for the "one word per group" rule
#define MODAL_GROUP_G0 0   // G4 G10 G28 G28.1 G30 G30.1 G53 G92 G92.1
#define MODAL_GROUP_G1 1   // G0 G1 G80
#define MODAL_GROUP_G2 2   // G17
#define MODAL_GROUP_G3 3   // G90 G91
#define MODAL_GROUP_G5 4   // G94
#define MODAL_GROUP_G6 5   // G21
#define MODAL_GROUP_G12 6  // G54..G59
#define MODAL_GROUP_G13 7  // G61
#define MODAL_GROUP_M4 8   // M0 M1 M2 M30
#define MODAL_GROUP_M7 9   // M5 (accepted, no spindle)
#define MODAL_GROUP_M8 10  // M9 (accepted, no coolant)

// Value words
#define WORD_F 0
#define WORD_L 1
#define WORD_N 2
#define WORD_P 3
#define WORD_X 4
#define WORD_Y 5
#define WORD_Z 6

#define AXIS_COMMAND_NONE 0
#define AXIS_COMMAND_NON_MODAL 1
#define AXIS_COMMAND_MOTION_MODE 2

#define FAIL(status) return (status)

void gc_init(void)
{
  memset(&gc_state, 0, sizeof(gc_state));
  gc_state.modal.motion = MOTION_MODE_SEEK;
  if (!settings_read_coord_data(gc_state.modal.coord_select, gc_state.coord_system))
    report_feedback_message(MESSAGE_COORD_CRC);
}

void gc_sync_position(void)
{
  int32_t steps[N_AXIS];
  system_get_position(steps);
  system_convert_array_steps_to_mpos(gc_state.position, steps);
}

uint8_t gc_execute_line(char *line, uint8_t jog)
{
  // Block: what this line asks for, filled by the parse, used by the actions.
  gc_modal_t modal = gc_state.modal;
  uint8_t non_modal = NON_MODAL_NONE;
  uint8_t axis_command = AXIS_COMMAND_NONE;
  uint8_t axis_words = 0;
  uint16_t command_words = 0;
  uint8_t value_words = 0;
  uint8_t program_flow = PROGRAM_FLOW_RUNNING;
  float f = 0, p = 0, xyz[N_AXIS] = {0, 0, 0};
  int32_t n = 0;
  uint8_t l = 0;

  if (jog) {
    // $J= lines: only G21, G90/G91, G53 and axis/F words; distance mode is local.
    modal.motion = MOTION_MODE_LINEAR;
  }

  uint8_t char_counter = 0;
  char letter;
  float value;
  uint8_t int_value = 0;
  uint16_t mantissa = 0;

  while ((letter = line[char_counter]) != 0) {
    if (letter < 'A' || letter > 'Z') FAIL(STATUS_EXPECTED_COMMAND_LETTER);
    char_counter++;
    if (!read_float(line, &char_counter, &value)) FAIL(STATUS_BAD_NUMBER_FORMAT);

    uint8_t word_bit;
    if (letter == 'G' || letter == 'M') {
      if (value < 0 || value > 255) FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
      // Integer part and hundredths, rounded half up as lroundf would, without
      // pulling lroundf and truncf in (the conversion truncates; frac - mantissa
      // is exact, so there is no double rounding as in (uint16_t)(frac + 0.5f)).
      int_value = (uint8_t)value;
      float frac = 100 * (value - int_value);
      mantissa = (uint8_t)frac;
      if (frac - mantissa >= 0.5f) mantissa++;
    }
    switch (letter) {
      case 'G':
        switch (int_value) {
          case 4: case 10: case 28: case 30: case 53: case 92:
            word_bit = MODAL_GROUP_G0;
            if (jog && int_value != 53) FAIL(STATUS_INVALID_JOG_COMMAND);
            if (int_value == 28 || int_value == 30) {
              if (mantissa == 0) non_modal = int_value;
              else if (mantissa == 10) { non_modal = int_value + 10; mantissa = 0; }
              else FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
            } else if (int_value == 92) {
              if (mantissa == 0) non_modal = NON_MODAL_SET_COORDINATE_OFFSET;
              else if (mantissa == 10) { non_modal = NON_MODAL_RESET_COORDINATE_OFFSET; mantissa = 0; }
              else FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
            } else {
              non_modal = int_value;
            }
            if (int_value != 4 && int_value != 53) {
              // These take axis words; so may a motion mode: only one may.
              if (axis_command) FAIL(STATUS_GCODE_AXIS_COMMAND_CONFLICT);
              axis_command = AXIS_COMMAND_NON_MODAL;
            }
            break;
          case 0: case 1: case 80:
            word_bit = MODAL_GROUP_G1;
            if (jog) FAIL(STATUS_INVALID_JOG_COMMAND);
            if (int_value == 80) {
              modal.motion = MOTION_MODE_NONE;
            } else {
              if (axis_command) FAIL(STATUS_GCODE_AXIS_COMMAND_CONFLICT);
              axis_command = AXIS_COMMAND_MOTION_MODE;
              modal.motion = int_value;
            }
            break;
          case 17: word_bit = MODAL_GROUP_G2; if (jog) FAIL(STATUS_INVALID_JOG_COMMAND); break;
          case 90: case 91:
            if (mantissa != 0) FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);  // G90.1/G91.1: arcs only
            word_bit = MODAL_GROUP_G3;
            modal.distance = int_value - 90;
            break;
          case 94: word_bit = MODAL_GROUP_G5; if (jog) FAIL(STATUS_INVALID_JOG_COMMAND); break;
          case 21: word_bit = MODAL_GROUP_G6; break;
          case 54: case 55: case 56: case 57: case 58: case 59:
            if (mantissa != 0) FAIL(STATUS_GCODE_UNSUPPORTED_COORD_SYS);
            if (jog) FAIL(STATUS_INVALID_JOG_COMMAND);
            word_bit = MODAL_GROUP_G12;
            modal.coord_select = int_value - 54;
            break;
          case 61:
            if (mantissa != 0 || jog) FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
            word_bit = MODAL_GROUP_G13;
            break;
          default: FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);  // G2/G3 arcs, G20 inches, G38 probe, G93 ...
        }
        if (mantissa > 0) FAIL(STATUS_GCODE_COMMAND_VALUE_NOT_INTEGER);
        if (bit_istrue(command_words, bit(word_bit))) FAIL(STATUS_GCODE_MODAL_GROUP_VIOLATION);
        command_words |= bit(word_bit);
        break;

      case 'M':
        if (jog) FAIL(STATUS_INVALID_JOG_COMMAND);
        if (mantissa > 0) FAIL(STATUS_GCODE_COMMAND_VALUE_NOT_INTEGER);
        switch (int_value) {
          case 0: case 1: case 2: case 30:
            word_bit = MODAL_GROUP_M4;
            program_flow = (int_value == 1) ? PROGRAM_FLOW_RUNNING : (int_value == 0 ? PROGRAM_FLOW_PAUSED : int_value);
            break;
          case 5: word_bit = MODAL_GROUP_M7; break;  // spindle off: there is none
          case 9: word_bit = MODAL_GROUP_M8; break;  // coolant off: there is none
          default: FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
        }
        if (bit_istrue(command_words, bit(word_bit))) FAIL(STATUS_GCODE_MODAL_GROUP_VIOLATION);
        command_words |= bit(word_bit);
        break;

      default:
        switch (letter) {
          case 'F': word_bit = WORD_F; f = value; break;
          case 'L': word_bit = WORD_L; if (value < 0 || value > 255) FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND); l = (uint8_t)value; if (l != value) FAIL(STATUS_GCODE_COMMAND_VALUE_NOT_INTEGER); break;
          case 'N': word_bit = WORD_N; if (value > MAX_LINE_NUMBER || value < 0) FAIL(STATUS_GCODE_INVALID_LINE_NUMBER); n = (int32_t)value; break;
          case 'P': word_bit = WORD_P; p = value; break;
          case 'X': word_bit = WORD_X; xyz[X_AXIS] = value; axis_words |= bit(X_AXIS); break;
          case 'Y': word_bit = WORD_Y; xyz[Y_AXIS] = value; axis_words |= bit(Y_AXIS); break;
          case 'Z': word_bit = WORD_Z; xyz[Z_AXIS] = value; axis_words |= bit(Z_AXIS); break;
          default: FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);  // A B C I J K R S T ... : not on this stage
        }
        if (bit_istrue(value_words, bit(word_bit))) FAIL(STATUS_GCODE_WORD_REPEATED);
        if (jog && !(word_bit == WORD_F || word_bit == WORD_N || word_bit >= WORD_X)) FAIL(STATUS_INVALID_JOG_COMMAND);
        if ((word_bit == WORD_F || word_bit == WORD_P) && value < 0.0f) FAIL(STATUS_NEGATIVE_VALUE);
        value_words |= bit(word_bit);
    }
  }

  // ---- Error checks on the whole line ----
  if (axis_words && !axis_command) axis_command = AXIS_COMMAND_MOTION_MODE;  // implicit motion mode
  if (jog) {
    if (!(value_words & bit(WORD_F))) FAIL(STATUS_GCODE_UNDEFINED_FEED_RATE);
    if (!axis_words) FAIL(STATUS_GCODE_NO_AXIS_WORDS);
  }

  // Feed: G94 units per minute. G1 needs one, now or earlier.
  float feed = (value_words & bit(WORD_F)) ? f : gc_state.feed_rate;
  if (!jog && axis_command == AXIS_COMMAND_MOTION_MODE && axis_words && modal.motion == MOTION_MODE_LINEAR && feed == 0.0f)
    FAIL(STATUS_GCODE_UNDEFINED_FEED_RATE);

  if (non_modal == NON_MODAL_DWELL) {
    if (!(value_words & bit(WORD_P))) FAIL(STATUS_GCODE_VALUE_WORD_MISSING);
    value_words &= ~bit(WORD_P);
  }

  float coord_data[N_AXIS];
  float block_coord_system[N_AXIS];
  memcpy(block_coord_system, gc_state.coord_system, sizeof(block_coord_system));
  if (command_words & bit(MODAL_GROUP_G12)) {
    if (modal.coord_select != gc_state.modal.coord_select) {
      if (!settings_read_coord_data(modal.coord_select, block_coord_system)) FAIL(STATUS_SETTING_READ_FAIL);
    }
  }

  uint8_t coord_select = 0;
  switch (non_modal) {
    case NON_MODAL_SET_COORDINATE_DATA:
      if (!axis_words) FAIL(STATUS_GCODE_NO_AXIS_WORDS);
      if ((value_words & (bit(WORD_P) | bit(WORD_L))) != (bit(WORD_P) | bit(WORD_L))) FAIL(STATUS_GCODE_VALUE_WORD_MISSING);
      if (p > N_COORDINATE_SYSTEM || p != (uint8_t)p) FAIL(STATUS_GCODE_UNSUPPORTED_COORD_SYS);
      if (l != 2 && l != 20) FAIL(STATUS_GCODE_UNSUPPORTED_COMMAND);
      coord_select = (p > 0) ? (uint8_t)p - 1 : modal.coord_select;
      value_words &= ~(bit(WORD_L) | bit(WORD_P));
      if (!settings_read_coord_data(coord_select, coord_data)) FAIL(STATUS_SETTING_READ_FAIL);
      for (uint8_t i = 0; i < N_AXIS; i++) {
        if (!(axis_words & bit(i))) continue;
        if (l == 20) {
          // L20: offset such that the current position reads xyz in that system.
          coord_data[i] = gc_state.position[i] - gc_state.coord_offset[i] - xyz[i];
        } else {
          coord_data[i] = xyz[i];
        }
      }
      break;
    case NON_MODAL_SET_COORDINATE_OFFSET:
      if (!axis_words) FAIL(STATUS_GCODE_NO_AXIS_WORDS);
      for (uint8_t i = 0; i < N_AXIS; i++)
        if (axis_words & bit(i)) xyz[i] = gc_state.position[i] - block_coord_system[i] - xyz[i];
        else xyz[i] = gc_state.coord_offset[i];
      break;
    default:
      // Axis words give a target: work coordinates to machine coordinates.
      if (axis_words) {
        for (uint8_t i = 0; i < N_AXIS; i++) {
          if (!(axis_words & bit(i))) {
            xyz[i] = gc_state.position[i];
          } else if (non_modal != NON_MODAL_ABSOLUTE_OVERRIDE) {
            if (modal.distance) xyz[i] += gc_state.position[i];
            else xyz[i] += block_coord_system[i] + gc_state.coord_offset[i];
          }
        }
      }
      switch (non_modal) {
        case NON_MODAL_GO_HOME_0: case NON_MODAL_GO_HOME_1:
          if (!settings_read_coord_data(non_modal == NON_MODAL_GO_HOME_0 ? SETTING_INDEX_G28 : SETTING_INDEX_G30, coord_data))
            FAIL(STATUS_SETTING_READ_FAIL);
          if (!axis_words) axis_command = AXIS_COMMAND_NONE;
          break;
        case NON_MODAL_SET_HOME_0: case NON_MODAL_SET_HOME_1:
          break;
        case NON_MODAL_ABSOLUTE_OVERRIDE:
          if (modal.motion != MOTION_MODE_SEEK && modal.motion != MOTION_MODE_LINEAR) FAIL(STATUS_GCODE_G53_INVALID_MOTION_MODE);
          break;
      }
  }

  if (axis_words && modal.motion == MOTION_MODE_NONE && axis_command == AXIS_COMMAND_MOTION_MODE)
    FAIL(STATUS_GCODE_AXIS_WORDS_EXIST);
  // Targets must stay representable in steps (a rotation stage never gets near).
  if (axis_command || jog) {
    const float *chk = (non_modal == NON_MODAL_GO_HOME_0 || non_modal == NON_MODAL_GO_HOME_1) ? coord_data : xyz;
    for (uint8_t i = 0; i < N_AXIS; i++) {
      if (fabsf(xyz[i] * settings.steps_per_deg[i]) > MAX_TARGET_STEPS ||
          fabsf(chk[i] * settings.steps_per_deg[i]) > MAX_TARGET_STEPS) FAIL(STATUS_GCODE_INVALID_TARGET);
    }
  }
  uint8_t has_n = value_words & bit(WORD_N);
  value_words &= ~(bit(WORD_N) | bit(WORD_F) | bit(WORD_X) | bit(WORD_Y) | bit(WORD_Z));
  if (value_words) FAIL(STATUS_GCODE_UNUSED_WORDS);

  // ---- Execute ----
  plan_line_data_t pl_data = {0};

  if (jog) {
    if (bit_istrue(settings.flags, BITFLAG_SOFT_LIMIT_ENABLE) && system_check_travel_limits(xyz))
      return STATUS_TRAVEL_EXCEEDED;
    pl_data.feed_rate = f;
    pl_data.condition = PL_COND_FLAG_JOG | PL_COND_FLAG_NO_FEED_OVERRIDE;
    mc_line(xyz, &pl_data);
    // Cancelled while its line was queued: the cancel's end sets the parser
    // to where the stage stopped (not yet, if it is still slowing down).
    if (sys.jog_cancelled) return STATUS_OK;
    if (sys.state == STATE_IDLE && !sys.abort) {
      if (plan_get_current_block() != NULL) {
        sys.state = STATE_JOG;
        st_prep_buffer();
        st_wake_up();
      }
    }
    memcpy(gc_state.position, xyz, sizeof(xyz));
    return STATUS_OK;
  }

  if (has_n) gc_state.line_number = n;
  gc_state.feed_rate = feed;
  pl_data.feed_rate = feed;

  if (non_modal == NON_MODAL_DWELL) mc_dwell(p);
  gc_state.modal.distance = modal.distance;

  if (gc_state.modal.coord_select != modal.coord_select) {
    gc_state.modal.coord_select = modal.coord_select;
    memcpy(gc_state.coord_system, block_coord_system, sizeof(block_coord_system));
  }

  // EEPROM writes stall the main loop for ms: let queued motion finish first (as GRBL).
  if (non_modal == NON_MODAL_SET_COORDINATE_DATA || non_modal == NON_MODAL_SET_HOME_0 || non_modal == NON_MODAL_SET_HOME_1) {
    protocol_buffer_synchronize();
    if (sys.abort) return STATUS_OK;
  }
  switch (non_modal) {
    case NON_MODAL_SET_COORDINATE_DATA:
      settings_write_coord_data(coord_select, coord_data);
      if (coord_select == gc_state.modal.coord_select) memcpy(gc_state.coord_system, coord_data, sizeof(coord_data));
      break;
    case NON_MODAL_GO_HOME_0: case NON_MODAL_GO_HOME_1:
      pl_data.condition = PL_COND_FLAG_RAPID_MOTION;
      if (axis_command) mc_line(xyz, &pl_data);   // via the intermediate point
      mc_line(coord_data, &pl_data);
      memcpy(gc_state.position, coord_data, sizeof(coord_data));
      break;
    case NON_MODAL_SET_HOME_0:
      settings_write_coord_data(SETTING_INDEX_G28, gc_state.position);
      break;
    case NON_MODAL_SET_HOME_1:
      settings_write_coord_data(SETTING_INDEX_G30, gc_state.position);
      break;
    case NON_MODAL_SET_COORDINATE_OFFSET:
      memcpy(gc_state.coord_offset, xyz, sizeof(xyz));
      break;
    case NON_MODAL_RESET_COORDINATE_OFFSET:
      memset(gc_state.coord_offset, 0, sizeof(gc_state.coord_offset));
      break;
  }

  gc_state.modal.motion = modal.motion;
  if (axis_command == AXIS_COMMAND_MOTION_MODE && axis_words && modal.motion != MOTION_MODE_NONE) {
    if (modal.motion == MOTION_MODE_SEEK) pl_data.condition = PL_COND_FLAG_RAPID_MOTION;
    mc_line(xyz, &pl_data);
    memcpy(gc_state.position, xyz, sizeof(xyz));
  }

  gc_state.modal.program_flow = program_flow;
  if (program_flow) {
    protocol_buffer_synchronize();
    if (program_flow == PROGRAM_FLOW_PAUSED) {
      if (sys.state != STATE_CHECK_MODE) {
        system_set_exec_state_flag(EXEC_FEED_HOLD);
        protocol_execute_realtime();
      }
    } else {
      // M2/M30: modes back to defaults, G92 kept (as GRBL).
      gc_state.modal.motion = MOTION_MODE_LINEAR;
      gc_state.modal.distance = 0;
      gc_state.modal.coord_select = 0;
      if (!settings_read_coord_data(0, gc_state.coord_system)) report_feedback_message(MESSAGE_COORD_CRC);
      if (sys.state != STATE_CHECK_MODE) report_feedback_message(MESSAGE_PROGRAM_END);
    }
    gc_state.modal.program_flow = PROGRAM_FLOW_RUNNING;
  }
  return STATUS_OK;
}
