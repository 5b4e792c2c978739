// Pin map: Arduino Uno + CNC shield (the only file that names pins).
// The simulated stage (sim/stage/stage.c) includes this file too: it takes
// the port letters and bit numbers from here, so the two cannot disagree.
#ifndef PINS_H
#define PINS_H

// Ports are named by letter; the registers follow from it (DDRx, PORTx, PINx).
#define PINS_CAT_(a, b) a##b
#define PINS_CAT(a, b) PINS_CAT_(a, b)

// Step pulse outputs: port D.
#define STEP_PORT_LETTER D
#define STEP_DDR  PINS_CAT(DDR, STEP_PORT_LETTER)
#define STEP_PORT PINS_CAT(PORT, STEP_PORT_LETTER)
#define X_STEP_BIT 2   // Uno Digital Pin 2
#define Y_STEP_BIT 3   // Uno Digital Pin 3
#define Z_STEP_BIT 4   // Uno Digital Pin 4
#define STEP_SHIFT 2   // axis bit i is port bit STEP_SHIFT + i
#define STEP_MASK ((1 << X_STEP_BIT) | (1 << Y_STEP_BIT) | (1 << Z_STEP_BIT))

// Direction outputs: port D.
#define DIR_PORT_LETTER D
#define DIR_DDR  PINS_CAT(DDR, DIR_PORT_LETTER)
#define DIR_PORT PINS_CAT(PORT, DIR_PORT_LETTER)
#define X_DIR_BIT 5    // Uno Digital Pin 5
#define Y_DIR_BIT 6    // Uno Digital Pin 6
#define Z_DIR_BIT 7    // Uno Digital Pin 7
#define DIR_SHIFT 5
#define DIR_MASK ((1 << X_DIR_BIT) | (1 << Y_DIR_BIT) | (1 << Z_DIR_BIT))

// Stepper driver enable (all axes): port B, active low on the shield.
#define ENABLE_PORT_LETTER B
#define ENABLE_DDR  PINS_CAT(DDR, ENABLE_PORT_LETTER)
#define ENABLE_PORT PINS_CAT(PORT, ENABLE_PORT_LETTER)
#define ENABLE_BIT 0   // Uno Digital Pin 8

// Limit switch inputs with pull-ups: port B. The switch closes to GND, so a
// triggered switch reads low ($5=0); $5=1 inverts for normally-closed ones.
#define LIMIT_PORT_LETTER B
#define LIMIT_DDR  PINS_CAT(DDR, LIMIT_PORT_LETTER)
#define LIMIT_PORT PINS_CAT(PORT, LIMIT_PORT_LETTER)
#define LIMIT_PIN  PINS_CAT(PIN, LIMIT_PORT_LETTER)
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
#if Y_STEP_BIT != X_STEP_BIT + 1 || Z_STEP_BIT != X_STEP_BIT + 2 || Y_DIR_BIT != X_DIR_BIT + 1 || \
    Z_DIR_BIT != X_DIR_BIT + 2 || Y_LIMIT_BIT != X_LIMIT_BIT + 1 || Z_LIMIT_BIT != X_LIMIT_BIT + 2
#error "axis pins must be consecutive, X first"
#endif

#endif
