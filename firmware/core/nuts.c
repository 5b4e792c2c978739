// Small helpers: number parsing, rounding, CRC.
#include "nuts.h"
#include "board.h"     // board_millis
#include "protocol.h"  // protocol_execute_realtime
#include "system.h"    // sys.abort

#define MAX_INT_DIGITS 8   // digits kept exactly in a uint32 (as GRBL)
#define MAX_EXPONENT 6     // numbers beyond 1e14 are refused as bad numbers

uint8_t read_float(const char *line, uint8_t *char_counter, float *value)
{
  const char *ptr = line + *char_counter;
  uint8_t c = *ptr++;
  uint8_t isnegative = 0;
  if (c == '-') { isnegative = 1; c = *ptr++; }
  else if (c == '+') { c = *ptr++; }

  uint32_t intval = 0;
  int16_t exp = 0;
  uint8_t ndigit = 0;    // significant digits (leading zeros do not count)
  uint8_t has_digit = 0;
  uint8_t isdecimal = 0;
  for (;;) {
    uint8_t d = c - '0';
    if (d <= 9) {
      has_digit = 1;
      if (d == 0 && ndigit == 0) {
        if (isdecimal && exp > -100) exp--;
      } else if (++ndigit <= MAX_INT_DIGITS) {
        if (isdecimal) exp--;
        intval = intval * 10 + d;
      } else {
        ndigit = MAX_INT_DIGITS + 1;
        if (!isdecimal && ++exp > MAX_EXPONENT) return 0;
      }
    } else if (c == '.' && !isdecimal) {
      isdecimal = 1;
    } else {
      break;
    }
    c = *ptr++;
  }
  if (!has_digit) return 0;

  float fval = (float)intval;
  if (fval != 0) {
    while (exp <= -2) { fval *= 0.01f; exp += 2; }
    if (exp < 0) fval *= 0.1f;
    else while (exp > 0) { fval *= 10.0f; exp--; }
  }
  *value = isnegative ? -fval : fval;
  *char_counter = ptr - line - 1;
  return 1;
}

int32_t nuts_lround(float v)
{
  // Saturate instead of overflowing (callers keep targets far inside this).
  if (v > 2.0e9f) return 2000000000L;
  if (v < -2.0e9f) return -2000000000L;
  return (v >= 0) ? (int32_t)(v + 0.5f) : -(int32_t)(-v + 0.5f);
}

uint16_t crc16_ccitt(uint16_t crc, const uint8_t *p, uint16_t n)
{
  while (n--) {
    crc ^= (uint16_t)(*p++) << 8;
    for (uint8_t i = 0; i < 8; i++)
      crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

void delay_ms_rt(uint16_t ms)
{
  uint32_t start = board_millis();
  while ((uint32_t)(board_millis() - start) < ms) {
    protocol_execute_realtime();
    if (sys.abort) return;
    board_idle();
  }
}
