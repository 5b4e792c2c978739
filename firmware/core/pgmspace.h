// Strings in flash on AVR, plain strings on the host.
#ifndef PGMSPACE_H
#define PGMSPACE_H
#ifdef __AVR__
#include <avr/pgmspace.h>
#else
#define PSTR(s) (s)
#define pgm_read_byte(p) (*(const unsigned char *)(p))
#define PROGMEM
#define memcpy_P(d, s, n) memcpy((d), (s), (n))
#endif
#endif
