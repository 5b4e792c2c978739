// Small helpers: number parsing, bit macros, CRC.
#ifndef NUTS_H
#define NUTS_H

#include <stdint.h>
#include "config.h"

#define bit(n) (1 << (n))
#define bit_true(x, mask) (x) |= (mask)
#define bit_false(x, mask) (x) &= ~(mask)
#define bit_istrue(x, mask) ((x & mask) != 0)
#define bit_isfalse(x, mask) ((x & mask) == 0)
#define min(a, b) (((a) < (b)) ? (a) : (b))
#define max(a, b) (((a) > (b)) ? (a) : (b))

uint8_t read_float(const char *line, uint8_t *char_counter, float *value); // main loop: parse [+-]digits[.digits] at line[*counter]; 1 on success
int32_t nuts_lround(float v);                       // any: round half away from zero
uint16_t crc16_ccitt(uint16_t crc, const uint8_t *p, uint16_t n); // main loop: CRC-16/CCITT-FALSE update (start with 0xFFFF)
void delay_ms_rt(uint16_t ms);                      // main loop: wait, running realtime commands; returns early on abort

#endif
