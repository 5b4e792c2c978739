// Real-time commands against interrupts that land inside the main loop's
// handling of them. The host port only runs ISRs in board_idle(), so this
// file compiles protocol.c itself with its reads of sys_rt_exec_state going
// through state_read(), where a test can deliver a byte to the UART ISR; the
// linker then takes these protocol functions instead of libcore.a's.
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <stdlib.h>
#include <cmocka.h>
#include "harness.h"
#include "nuts.h"
#include "codes.h"

static int16_t byte_at_state_read = -1;   // delivered at the next read, then -1

static volatile uint8_t *state_read(void)
{
  if (byte_at_state_read >= 0) {
    uint8_t c = (uint8_t)byte_at_state_read;
    byte_at_state_read = -1;
    serial_rx_isr(c);
  }
  return &sys_rt_exec_state;
}

#define sys_rt_exec_state (*state_read())
#include "protocol.c"
#undef sys_rt_exec_state

// Ctrl-X mid-move after protocol_exec_rt_system has read no alarm but before
// it reads EXEC_RESET: mc_reset raised both, so the reset must still say
// ALARM:3 and come up locked (steps may be lost), never Idle.
static void test_reset_between_alarm_and_state_reads(void **state)
{
  const char *move = "G1 X30 F900\n";
  h_send_bytes(move, strlen(move));
  while (host_motor_steps[0] < 800) {
    protocol_poll();
    assert_int_equal(sys.abort, 0);
  }
  assert_int_equal(sys.state, STATE_CYCLE);
  assert_int_equal(sys_rt_exec_alarm, 0);
  h_take();

  byte_at_state_read = CMD_RESET;
  protocol_execute_realtime();
  assert_int_equal(byte_at_state_read, -1);   // the ISR ran between the two reads
  assert_int_equal(sys.abort, 1);
  protocol_reset();   // as main() does after an abort

  const char *out = h_take();
  const char *alarm = strstr(out, "ALARM:3");
  const char *banner = strstr(out, "Grbl ");
  assert_non_null(alarm);
  assert_non_null(banner);
  assert_true(alarm < banner);
  assert_non_null(strstr(banner, "[MSG:'$H'|'$X' to unlock]"));
  assert_int_equal(sys.state, STATE_ALARM);
  for (int a = 0; a < 3; a++) assert_int_equal(sys_position[a], host_motor_steps[a]);
}

int main(void)
{
  const struct CMUnitTest tests[] = {
    cmocka_unit_test_setup(test_reset_between_alarm_and_state_reads, h_new_chip),
  };
  if (getenv("TEST_FILTER")) cmocka_set_test_filter(getenv("TEST_FILTER"));
  return cmocka_run_group_tests_name("realtime", tests, NULL, NULL);
}
