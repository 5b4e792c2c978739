// libFuzzer target: arbitrary bytes on the serial line, through the
// real-time filter, the line reader, the G-code and '$' parsers, the planner
// and the simulated stepper. Each input starts from the same EEPROM image
// and gets a bounded amount of simulated time (then a reset, as a user
// would send). After the final reset the counted position must equal the
// steps the motors made (unless backlash or homing made them differ on purpose).
#include <stdint.h>
#include <stddef.h>
#include <stdlib.h>
#include "harness.h"
#include "motion.h"

#define BUDGET_CYCLES (F_CPU / 5)   // 200 ms of simulated time per input

static uint8_t eeprom_image[HOST_EEPROM_SIZE];
static uint64_t budget_end;
static int initialised;

static int dir_inverted;   // $3 was non-zero at some point: motors ran against the count
static int exempt;          // homing or backlash ran: position and motor differ on purpose

static void budget_hook(void)
{
  if (settings.dir_invert_mask) dir_inverted = 1;
  if (sys.state == STATE_HOMING) exempt = 1;
  if (settings.backlash[0] > 0 || settings.backlash[1] > 0 || settings.backlash[2] > 0) exempt = 1;  // take-up steps are not counted
  if (host_cycles > budget_end) serial_rx_isr(0x18);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
  if (!initialised) {
    h_erase_eeprom();
    h_boot();
    memcpy(eeprom_image, host_eeprom, sizeof(eeprom_image));
    initialised = 1;
  }
  memcpy(host_eeprom, eeprom_image, sizeof(eeprom_image));
  memset(host_motor_steps, 0, sizeof(host_motor_steps));
  for (int i = 0; i < 3; i++) host_limit_at[i] = INT32_MAX;
  host_limit_raw = 7;
  host_idle_hook = NULL;
  h_boot();
  h_take();

  budget_end = host_cycles + BUDGET_CYCLES;
  dir_inverted = 0;
  exempt = 0;
  host_idle_hook = budget_hook;
  h_send_bytes((const char *)data, size);
  h_run(1000);
  // End with a reset and check the position bookkeeping.
  serial_rx_isr(0x18);
  h_run(1000);
  host_idle_hook = NULL;
  h_take();

  // Homing resets the position; $3 flips a motor's direction against the count.
  int homing = exempt || dir_inverted;
  if (!homing) {
    for (int a = 0; a < 3; a++) {
      if (sys_position[a] != host_motor_steps[a]) {
        fprintf(stderr, "position %d != motor %d on axis %d\n", sys_position[a], host_motor_steps[a], a);
        abort();
      }
    }
  }
  return 0;
}
