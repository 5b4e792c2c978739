// Limit switches: hard-limit alarm, soft limits, homing.
#ifndef LIMITS_H
#define LIMITS_H

#include <stdint.h>

void limits_init(void);                  // main loop: hard-limit interrupt on/off from $21
uint8_t limits_get_state(void);          // any: triggered switches, bit 0 = X ($5 applied)
void limits_pin_change_isr(void);        // limit pin-change ISR: starts the debounce of a closed switch
void limits_tick_isr(void);              // 1 kHz timer ISR: hard-limit alarm once the debounce ran out
void limits_go_home(uint8_t cycle_mask); // main loop: seek, locate, pull off the axes in cycle_mask
void limits_soft_check(const float *target); // main loop: alarm 2 when target (deg) is outside travel

#endif
