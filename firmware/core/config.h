// Compile-time configuration of the stage firmware. Each option says why.
#ifndef CONFIG_H
#define CONFIG_H

#define N_AXIS 3               // X rides on Y, which rides on Z (conventions.md)
#define X_AXIS 0
#define Y_AXIS 1
#define Z_AXIS 2

#define BAUD_RATE 115200UL     // GRBL 1.1 senders assume it
#define RX_BUFFER_SIZE 128     // advertised ([OPT:..,128]): character-counting senders assume 128 (GRBL)
// Room behind the advertised buffer. GRBL's ring holds 127 of its 128, and
// real senders overfill it: some count all 128, some send '$G', '$#' or '$$'
// outside their count (a well-known web sender polls '$G' twice a second).
// The ring takes one more full line (80 + CR LF) and a few such commands, so
// none of those bytes is lost; 'Bf:' still reports against the 128.
#define RX_HEADROOM 96
#define RX_RING_SIZE (RX_BUFFER_SIZE + RX_HEADROOM)
#define TX_BUFFER_SIZE 64      // replies are short; a status report fits twice
#define LINE_BUFFER_SIZE 81    // 80 characters + NUL, as GRBL

// Planner look-ahead depth. GRBL uses 16 on the 328P; a rotation stage runs
// few, long moves, and 10 keeps static RAM under 1.3 KB.
#define BLOCK_BUFFER_SIZE 10
#define SEGMENT_BUFFER_SIZE 6  // step segments prepared ahead (~60 ms at 100 Hz)

// Segments are planned every 1/100 s of motion, like GRBL.
#define ACCELERATION_TICKS_PER_SECOND 100
#define REQ_MM_INCREMENT_SCALAR 1.25f

#define MINIMUM_JUNCTION_SPEED 0.0f   // deg/min
#define MINIMUM_FEED_RATE 1.0f        // deg/min; slower feeds are raised to it
#define MAX_LINE_NUMBER 10000000L     // GRBL's N limit
// Long moves are split into blocks of at most this many degrees: a block's
// remaining length is a float, and at the slowest feed a 10 ms segment must
// still move it by more than its rounding step.
#define MAX_BLOCK_DEG 720.0f
// ... and of at most this many steps on any axis: the segment prep counts a
// block's steps down in a float, exact only up to 2^24 (above, a block's
// count was rounded and the motor ran up to 64 steps short or long). The
// margin below 2^24 covers the rounding of the pieces' ends (float degrees:
// ~60 steps at MAX_TARGET_STEPS). It also keeps the step ISR's doubled
// Bresenham sums (up to 4x a block's steps) inside uint32_t for mc_line's
// blocks; a homing seek (1.5 x $130 at $100) is not cut, and only settings
// far beyond any stage's (over 2^30 steps in one seek) would overflow them.
#define MAX_BLOCK_STEPS 16000000.0f
#define MAX_TARGET_STEPS 1.0e9f       // |target| in steps; keeps step deltas inside int32 (error:33 beyond)
// Slowest acceleration, deg/s^2: $120-$122 below it are refused (error:3),
// raised to it when loaded from an older firmware's EEPROM (settings_init),
// and the planner raises a lower one to it.
// The segment prep subtracts each part of a segment from the block's remaining
// distance on its own. From rest, a segment stretched to MAX_SEGMENT_MIN
// (stepper.c) ends with a part of t = 2^18 DT_SEGMENT = 43.7 min that moves
// 1.5 a t^2; unless that exceeds half the float step of a MAX_BLOCK_DEG block
// (2^-15 deg), i.e. a > 1.1e-8 deg/min^2 = 3e-12 deg/s^2, the first segments
// move nothing and progress becomes unboundedly slow as a falls: not exactly
// zero (the speed still grows by a t each segment, exactly so from rest, and
// stops growing only after ~2^24 segments), but the prep all but spins.
// 0.1 deg/s^2 is far above that (a 720-deg block from rest moves
// within 40 ms) and far below what a stage needs to move in useful time (it
// takes 5 minutes to reach 30 deg/s).
#define MINIMUM_ACCELERATION 0.1f
// Coarsest drive, steps/deg: $100-$102 below it are refused (error:3), and
// raised to it when loaded from an older firmware's EEPROM. The
// segment prep covers at most MAX_SEGMENT_MIN (60 min) of motion per pass, 60
// deg at MINIMUM_FEED_RATE, and a pass that makes no step is followed at once
// by another: at 0.01 steps/deg (a step every 100 deg) the second makes one.
// At 1e-9 steps/deg it passed millions of times before a step, holding the
// main loop (10 s of host CPU for one fuzz input). A full-step 1.8-deg motor
// driving the stage directly has 0.56 steps/deg.
#define MINIMUM_STEPS_PER_DEG 0.01f
#define N_COORDINATE_SYSTEM 6         // G54..G59
#define N_DECIMAL_COORDVALUE 3        // positions printed with 3 decimals (deg)
#define N_DECIMAL_SETTINGVALUE 3
#define DWELL_TIME_STEP_MS 50         // G4 and homing debounce poll realtime this often

// Step timing. Timer1 in CTC mode: OCR1A is the step period, OCR1B ends the
// pulse. Both are never 0 (simavr 1.6 never fires a CTC compare of 0), and
// TCNT1 is never preloaded (starting the clock resets it in simavr).
// The pulse-end compare is set from the counter when the pins go high, so
// a late step interrupt cannot shorten the pulse; the period must leave room
// for the interrupt's own latency and run time as well.
#define STEP_PULSE_LATENCY_CYCLES 96
#define STEP_LOW_MIN_CYCLES 64        // minimum low time before the next pulse
#define MAX_STEP_RATE_HZ 40000UL      // settings are refused above this ($100*$110/60)

// Hard limits act when a switch still reads closed this long after its pin
// changed: a bouncing contact (or noise on the wires) that opens again is no
// alarm, e.g. while moving off a switch after '$X'. At the fastest rate
// (30 deg/s) the stage runs 0.3 deg further into a real hit. (GRBL's optional
// software debounce waits ~32 ms on the watchdog.)
#define HARD_LIMIT_DEBOUNCE_MS 10

// Homing, as GRBL: seek, pull off, locate slowly, pull off.
#define HOMING_AXIS_SEARCH_SCALAR 1.5f  // seek travel = 1.5 x max travel
#define HOMING_AXIS_LOCATE_SCALAR 5.0f  // locate travel = 5 x pull-off
#define N_HOMING_LOCATE_CYCLE 1
#define HOMING_CYCLE_MASK ((1 << X_AXIS) | (1 << Y_AXIS) | (1 << Z_AXIS)) // independent stages home together

// Overrides, as GRBL 1.1h: feed 10..200 % in steps of 10 and 1, rapid 100/50/25 %.
#define DEFAULT_FEED_OVERRIDE 100
#define MAX_FEED_RATE_OVERRIDE 200
#define MIN_FEED_RATE_OVERRIDE 10
#define FEED_OVERRIDE_COARSE_INCREMENT 10
#define FEED_OVERRIDE_FINE_INCREMENT 1
#define DEFAULT_RAPID_OVERRIDE 100
#define RAPID_OVERRIDE_MEDIUM 50
#define RAPID_OVERRIDE_LOW 25

// Status report refresh counts for the WCO and Ov fields (GRBL 1.1h values).
#define REPORT_OVR_REFRESH_BUSY_COUNT 20
#define REPORT_OVR_REFRESH_IDLE_COUNT 10
#define REPORT_WCO_REFRESH_BUSY_COUNT 30
#define REPORT_WCO_REFRESH_IDLE_COUNT 10

#define GRBL_VERSION "1.1h"
#define GRBL_VERSION_BUILD "20261122"
#define FIRMWARE_NAME "spherepose stage"

#if N_AXIS != 3
#error "the pin map and reports are written for three axes"
#endif
#if RX_RING_SIZE > 255 || TX_BUFFER_SIZE > 255
#error "serial ring indices are 8-bit"
#endif
#if BLOCK_BUFFER_SIZE < 2 || SEGMENT_BUFFER_SIZE < 2
#error "planner and segment buffers need at least two entries"
#endif
#if STEP_LOW_MIN_CYCLES < 32
#error "step low time must cover the pulse-end interrupt"
#endif

#endif
