// spherepose stage firmware: initialise in order, then run the main loop.
#include "../core/board.h"
#include "../core/serial.h"
#include "../core/settings.h"
#include "../core/protocol.h"

int main(void)
{
  board_init();
  serial_init();
  settings_init();
  protocol_init();
  for (;;) {
    protocol_reset();       // banner; after 0x18 the position is kept
    protocol_main_loop();   // returns on reset
  }
}
