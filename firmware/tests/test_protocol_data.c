// Protocol scripts: files of lines sent and replies expected, run against
// the core built for the host.
//
//   > TEXT        send TEXT and a newline, run until quiet
//   >> TEXT       send TEXT and a newline, run only until it is read (motion goes on)
//   >+ TEXT       put TEXT and a newline into the receive ring at once, whatever room
//                 is left (a sender that overfills); nothing runs (then "= run" or ">")
//   >! HEX ...    send raw bytes (real-time commands, control bytes), run until quiet
//   >@ MS HEX     deliver a raw byte at MS simulated milliseconds from now (then use "= run")
//   < TEXT        the next reply line is exactly TEXT
//   <~ PREFIX     the next reply line starts with PREFIX
//   <* TEXT       skip reply lines until one equals TEXT
//   = run MS      let MS milliseconds pass
//   = boot        power-cycle, EEPROM kept;  = erase  blank EEPROM
//   = steps X Y Z the motors moved exactly this many steps since power-on
//   = corrupt ADDR  flip a bit in EEPROM;  = watchdog  the next boot follows a watchdog reset
//   = stack 0|1   the stack guard reports an overflow (0) or not (1)
//   = limit AXIS STEPS  the axis' switch closes at motor step STEPS and beyond
//   = pins MASK   drive the limit pins (bit i = axis i, 1 = open), as a glitch or a bounce would
//   # comment
// Every reply line must be matched before the next '>' line.
#include <stdlib.h>
#include <stdint.h>
#include "harness.h"

static int failures;
static const char *cur_file;
static int cur_line;
static char pending[1 << 16];
static size_t pend_pos, pend_len;

static void fail(const char *what, const char *got)
{
  fprintf(stderr, "%s:%d: %s (got: \"%s\")\n", cur_file, cur_line, what, got ? got : "<nothing>");
  failures++;
}

static void pull(void)
{
  const char *t = h_take();
  size_t n = strlen(t);
  if (pend_len + n >= sizeof(pending)) n = sizeof(pending) - pend_len - 1;
  memcpy(pending + pend_len, t, n);
  pend_len += n;
  pending[pend_len] = 0;
}

// Next non-empty reply line, or NULL.
static const char *next_line(void)
{
  static char l[1024];
  pull();
  for (;;) {
    if (pend_pos >= pend_len) return NULL;
    char *e = strstr(pending + pend_pos, "\r\n");
    if (!e) return NULL;
    size_t n = e - (pending + pend_pos);
    if (n >= sizeof(l)) n = sizeof(l) - 1;
    memcpy(l, pending + pend_pos, n);
    l[n] = 0;
    pend_pos = e - pending + 2;
    if (n) return l;
  }
}

static void check_all_matched(void)
{
  const char *l;
  while ((l = next_line())) fail("unexpected reply", l);
  pend_pos = pend_len = 0;
}

static void send_hex(const char *p)
{
  char buf[256];
  size_t n = 0;
  char *end;
  for (;;) {
    long v = strtol(p, &end, 16);
    if (end == p || n >= sizeof(buf)) break;
    buf[n++] = (char)v;
    p = end;
  }
  h_send_bytes(buf, n);
  h_run(600000);
}

static void run_file(const char *path)
{
  FILE *f = fopen(path, "r");
  if (!f) { fprintf(stderr, "%s: cannot open\n", path); failures++; return; }
  cur_file = path;
  cur_line = 0;
  h_erase_eeprom();
  memset(host_motor_steps, 0, sizeof(host_motor_steps));
  for (int i = 0; i < 3; i++) host_limit_at[i] = INT32_MAX;
  host_limit_raw = 7;
  pend_pos = pend_len = 0;
  h_boot();
  char line[1024];
  while (fgets(line, sizeof(line), f)) {
    cur_line++;
    line[strcspn(line, "\r\n")] = 0;
    if (line[0] == '#' || line[0] == 0) continue;
    if (!strncmp(line, ">! ", 3)) { check_all_matched(); send_hex(line + 3); }
    else if (!strncmp(line, ">@ ", 3)) {
      char *e; unsigned long ms = strtoul(line + 3, &e, 10);
      host_schedule_byte(board_millis() + ms, (uint8_t)strtol(e, NULL, 16));
    }
    else if (!strncmp(line, ">> ", 3)) {
      // Send without waiting for motion to finish: only until the line is read.
      check_all_matched();
      h_send_bytes(line + 3, strlen(line + 3));
      h_send_bytes("\n", 1);
      for (int i = 0; i < 1000 && serial_get_rx_buffer_available() < RX_BUFFER_SIZE - 1; i++) protocol_poll();
      protocol_poll();
    }
    else if (!strncmp(line, ">+ ", 3)) {
      for (const char *p = line + 3; *p; p++) serial_rx_isr((uint8_t)*p);
      serial_rx_isr('\n');
    }
    else if (!strncmp(line, "> ", 2) || !strcmp(line, ">")) { check_all_matched(); h_send(line[1] ? line + 2 : ""); }
    else if (!strncmp(line, "<~ ", 3)) {
      const char *l = next_line();
      if (!l || strncmp(l, line + 3, strlen(line + 3))) fail(line, l);
    } else if (!strncmp(line, "<* ", 3)) {
      const char *l;
      while ((l = next_line()) && strcmp(l, line + 3)) {}
      if (!l) fail(line, NULL);
    } else if (!strncmp(line, "< ", 2) || !strcmp(line, "<")) {
      const char *l = next_line();
      const char *want = line[1] ? line + 2 : "";
      if (!l || strcmp(l, want)) fail(line, l);
    } else if (!strncmp(line, "= run ", 6)) { host_advance_ms(atoi(line + 6)); h_run(600000); }
    else if (!strcmp(line, "= boot")) { check_all_matched(); h_boot(); }
    else if (!strcmp(line, "= erase")) h_erase_eeprom();
    else if (!strcmp(line, "= watchdog")) host_watchdog_reset = 1;
    else if (!strncmp(line, "= stack ", 8)) host_stack_ok = (uint8_t)atoi(line + 8);
    else if (!strncmp(line, "= pins ", 7)) host_set_limit_raw((uint8_t)atoi(line + 7));
    else if (!strncmp(line, "= corrupt ", 10)) host_eeprom[atoi(line + 10)] ^= 0x10;
    else if (!strncmp(line, "= limit ", 8)) {
      int ax; long st;
      if (sscanf(line + 8, "%d %ld", &ax, &st) == 2 && ax >= 0 && ax < 3) host_limit_at[ax] = (int32_t)st;
    } else if (!strncmp(line, "= steps ", 8)) {
      long x, y, z;
      char msg[128];
      if (sscanf(line + 8, "%ld %ld %ld", &x, &y, &z) != 3) { fail("bad = steps line", line); continue; }
      if (x != host_motor_steps[0] || y != host_motor_steps[1] || z != host_motor_steps[2]) {
        snprintf(msg, sizeof(msg), "%d %d %d", host_motor_steps[0], host_motor_steps[1], host_motor_steps[2]);
        fail(line, msg);
      }
    } else {
      fail("unknown script line", line);
    }
  }
  check_all_matched();
  host_watchdog_reset = 0;
  host_stack_ok = 1;
  fclose(f);
}

int main(int argc, char **argv)
{
  for (int i = 1; i < argc; i++) run_file(argv[i]);
  if (failures) { fprintf(stderr, "protocol scripts: %d failure(s)\n", failures); return 1; }
  printf("  protocol scripts: %d file(s) passed\n", argc - 1);
  return 0;
}
