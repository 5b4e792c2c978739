/* eefile.h: the EEPROM kept in a file between runs. The file is the raw
 * EEPROM image (1024 bytes on the atmega328p, erased bytes are 0xff). */
#ifndef EEFILE_H
#define EEFILE_H

#include <stdint.h>
#include "sim_avr.h"
#include "err.h" /* ERR_LEN: err[] buffers */

#define EE_MAX 4096

struct eefile {
    avr_t *avr;
    char path[512];
    uint32_t size;
    uint8_t saved[EE_MAX]; /* what the file holds now */
};

/* Load path into the simulated EEPROM when it exists (a missing file means
 * a blank, erased EEPROM; a file of the wrong size is an error). */
int ee_load(struct eefile *e, avr_t *avr, const char *path, char *err);

/* Write the EEPROM to the file when it changed since the last save:
 * temporary file, fsync, rename, so a crash never leaves half a file. */
int ee_save(struct eefile *e, char *err);

#endif
