#!/bin/bash
# The flashing path end to end, without a board: stagesim boots Optiboot on a
# blank chip (fuses as on the Uno), avrdude programs HEX over the pty exactly
# as `make flash` programs a board (-c arduino -b 115200, write and verify),
# then the firmware must greet. The EEPROM file is kept (avrdude writes flash
# only). Usage: tests/flash_sim.sh HEX EEPROM_FILE   (from firmware/)
set -euo pipefail
HEX=${1:?usage: flash_sim.sh HEX EEPROM_FILE}
EEPROM=${2:?usage: flash_sim.sh HEX EEPROM_FILE}
SIM=../sim/stage
STAGESIM=$SIM/build/stagesim
BOOT=$SIM/build/optiboot_atmega328.hex

make -s -C $SIM all optiboot
RUN=$(mktemp -d)
SIM_PID=
cleanup() {
  [ -n "$SIM_PID" ] && kill "$SIM_PID" 2>/dev/null && wait "$SIM_PID" 2>/dev/null || true
  rm -rf "$RUN"
}
trap cleanup EXIT

$STAGESIM --bootloader $BOOT --eeprom "$EEPROM" > "$RUN/out" 2> "$RUN/err" &
SIM_PID=$!
for _ in $(seq 100); do grep -q '^PTY ' "$RUN/out" 2>/dev/null && break; sleep 0.1; done
PTY=$(sed -n 's/^PTY //p' "$RUN/out")
[ -n "$PTY" ] || { echo "flash-sim: stagesim did not start:"; cat "$RUN/err"; exit 1; }
echo "  FLASH   $HEX -> Optiboot in stagesim ($PTY)"

# The first client of a fresh stagesim finds the chip as powered up (no
# reset); here that is stty. Then avrdude opens the port (DTR resets the
# chip, Optiboot waits for it),
# writes, reads back and compares; a pty has no modem lines, so its
# TIOCMGET complaints are expected and filtered.
stty -F "$PTY" raw -echo
if ! avrdude -p atmega328p -c arduino -P "$PTY" -b 115200 -D -U "flash:w:$HEX:i" > "$RUN/avrdude" 2>&1; then
  cat "$RUN/avrdude"; echo "flash-sim: avrdude failed"; exit 1
fi
grep -v TIOCMGET "$RUN/avrdude" | grep -E "bytes of flash (written|verified)" | sed 's/^/  /'
grep -q "bytes of flash verified" "$RUN/avrdude" || { cat "$RUN/avrdude"; exit 1; }

# The application runs: opening the port resets the chip again, Optiboot
# waits for a programmer, then starts it, and it greets.
exec 3<> "$PTY"
stty -F "$PTY" raw -echo
if ! timeout 20 grep -a -m1 '^Grbl ' <&3 > "$RUN/banner"; then
  exec 3<&-
  echo "flash-sim: no banner after flashing"; cat "$RUN/err"; exit 1
fi
exec 3<&-
echo "  BANNER  $(tr -d '\r' < "$RUN/banner")"
kill "$SIM_PID"
wait "$SIM_PID" || { echo "flash-sim: stagesim exit $?"; cat "$RUN/err"; exit 1; }
SIM_PID=
