/* err.h -- the one error convention of sim/stage (stage model, pty bridge,
 * state socket, EEPROM file, stagesim): a function that fails returns -1 and
 * fills its caller's err buffer, ERR_LEN bytes, with "call: reason"
 * (snprintf(err, ERR_LEN, ...), truncated when longer). */
#ifndef SIM_STAGE_ERR_H
#define SIM_STAGE_ERR_H

#define ERR_LEN 256 /* size of every err[] buffer in sim/stage */

#endif
