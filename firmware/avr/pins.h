// Pin map: Arduino Uno + CNC shield (the only file that names pins).
// The simulated stage (sim/stage) reads this file too.
#ifndef PINS_H
#define PINS_H

// Step pulse outputs: port D.
#define STEP_DDR  DDRD
#define STEP_PORT PORTD
#define X_STEP_BIT 2   // Uno Digital Pin 2
#define Y_STEP_BIT 3   // Uno Digital Pin 3
#define Z_STEP_BIT 4   // Uno Digital Pin 4
#define STEP_SHIFT 2   // axis bit i is port bit STEP_SHIFT + i
#define STEP_MASK ((1 << X_STEP_BIT) | (1 << Y_STEP_BIT) | (1 << Z_STEP_BIT))

// Direction outputs: port D.
#define DIR_DDR  DDRD
#define DIR_PORT PORTD
#define X_DIR_BIT 5    // Uno Digital Pin 5
#define Y_DIR_BIT 6    // Uno Digital Pin 6
#define Z_DIR_BIT 7    // Uno Digital Pin 7
#define DIR_SHIFT 5
#define DIR_MASK ((1 << X_DIR_BIT) | (1 << Y_DIR_BIT) | (1 << Z_DIR_BIT))

// Stepper driver enable (all axes): port B, active low on the shield.
#define ENABLE_DDR  DDRB
#define ENABLE_PORT PORTB
#define ENABLE_BIT 0   // Uno Digital Pin 8

// Limit switch inputs with pull-ups: port B. The switch closes to GND, so a
// triggered switch reads low ($5=0); $5=1 inverts for normally-closed ones.
#define LIMIT_DDR  DDRB
#define LIMIT_PORT PORTB
#define LIMIT_PIN  PINB
#define X_LIMIT_BIT 1  // Uno Digital Pin 9
#define Y_LIMIT_BIT 2  // Uno Digital Pin 10
#define Z_LIMIT_BIT 3  // Uno Digital Pin 11
#define LIMIT_SHIFT 1
#define LIMIT_MASK ((1 << X_LIMIT_BIT) | (1 << Y_LIMIT_BIT) | (1 << Z_LIMIT_BIT))
#define LIMIT_PCMSK PCMSK0 // pin-change interrupt 0 covers port B
#define LIMIT_PCIE  PCIE0

#if STEP_SHIFT != X_STEP_BIT || DIR_SHIFT != X_DIR_BIT || LIMIT_SHIFT != X_LIMIT_BIT
#error "axis pins must be consecutive, X first"
#endif

#endif
