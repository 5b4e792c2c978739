// simrun: run the firmware ELF in simavr with a timed script of serial input,
// print what it sends, count step pulses per axis. A development and
// benchmark aid for the firmware alone (sim/stage is the full simulated stage).
//
//   simrun FIRMWARE.elf SCRIPT [EEPROM_FILE]
//
// SCRIPT lines: "<ms> <text>" sends text + "\n" at <ms> simulated milliseconds;
// "<ms> !<hex>" sends one raw byte (e.g. "!18" reset, "!3f" '?');
// "<ms> limit <axis> <0|1>" drives a limit pin (1 = triggered, pin low);
// "<ms> end" stops. Output ends with one "STEPS x y z" line and timing stats.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <avr_uart.h>
#include <avr_ioport.h>
#include <avr_eeprom.h>

#define F 16000000UL
#define BYTE_CYCLES 1389   // one byte at 115200 baud

static avr_t *avr;
static long steps[3];
static uint8_t dir[3];
static avr_cycle_count_t rise[3], last_rise[3], first_rise[3];
static avr_cycle_count_t min_pulse = (avr_cycle_count_t)-1, min_interval[3];
static unsigned char sendq[65536];
static size_t sq_head, sq_tail;
static int uart_xoff;
static long n_short;

// Streaming mode ("<ms> stream FILE POLL_MS"): send FILE's lines with GRBL
// character counting (at most 127 bytes unanswered), '?' every POLL_MS.
static FILE *stream_f;
static int stream_inflight[512], stream_head, stream_tail, stream_bytes;
static long stream_sent, stream_ok, stream_err;
static char outline[256];
static int outlen;
static int quiet;

static void uart_out(struct avr_irq_t *irq, uint32_t v, void *p)
{
  if (!quiet) { putchar((int)v); fflush(stdout); }
  if (v == '\n') {
    outline[outlen] = 0;
    if (!strncmp(outline, "ok", 2) || !strncmp(outline, "error:", 6)) {
      if (outline[0] == 'e') { stream_err++; if (quiet) fprintf(stdout, "%s\n", outline); }
      else stream_ok++;
      if (stream_head != stream_tail) {
        stream_bytes -= stream_inflight[stream_tail];
        stream_tail = (stream_tail + 1) % 512;
      }
    }
    outlen = 0;
  } else if (v != '\r' && outlen < 255) {
    outline[outlen++] = (char)v;
  }
}

static void xon(struct avr_irq_t *irq, uint32_t v, void *p) { uart_xoff = 0; }
static void xoff(struct avr_irq_t *irq, uint32_t v, void *p) { uart_xoff = 1; }

static void pin_change(struct avr_irq_t *irq, uint32_t v, void *p)
{
  int pin = (int)(intptr_t)p;
  static long long t0 = -1, t1 = -1;
  if (t0 < 0) { char *e = getenv("SIMRUN_TRACE"); if (e) sscanf(e, "%lld,%lld", &t0, &t1); }
  if (t0 >= 0 && (long long)avr->cycle >= t0 && (long long)avr->cycle <= t1)
    fprintf(stderr, "pin D%d=%u at %llu\n", pin, v, (unsigned long long)avr->cycle);
  if (pin >= 5) { dir[pin - 5] = v; return; }
  int a = pin - 2;
  if (v) {
    rise[a] = avr->cycle;
    if (!first_rise[a]) first_rise[a] = avr->cycle;
    steps[a] += dir[a] ? -1 : 1;
    if (last_rise[a]) {
      avr_cycle_count_t d = avr->cycle - last_rise[a];
      if (!min_interval[a] || d < min_interval[a]) min_interval[a] = d;
      if (d < 300 && getenv("SIMRUN_DEBUG")) fprintf(stderr, "close steps axis %d: %llu cycles at %llu\n", a, (unsigned long long)d, (unsigned long long)avr->cycle);
    }
    last_rise[a] = avr->cycle;
  } else if (rise[a]) {
    avr_cycle_count_t w = avr->cycle - rise[a];
    if (w < min_pulse) min_pulse = w;
    if (w < 160) { n_short++; if (getenv("SIMRUN_DEBUG")) fprintf(stderr, "short pulse axis %d: %llu cycles at %llu\n", a, (unsigned long long)w, (unsigned long long)avr->cycle); }
  }
}

static avr_cycle_count_t feed(struct avr_t *a, avr_cycle_count_t when, void *p)
{
  if (sq_head != sq_tail && !uart_xoff) {
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), sendq[sq_tail]);
    sq_tail = (sq_tail + 1) % sizeof(sendq);
  }
  return when + BYTE_CYCLES;
}

static void enqueue(unsigned char c)
{
  sendq[sq_head] = c;
  sq_head = (sq_head + 1) % sizeof(sendq);
}

static char stream_next[128];
static int stream_have;

static void stream_pump(void)
{
  if (!stream_f) return;
  for (;;) {
    if (!stream_have) {
      if (!fgets(stream_next, sizeof(stream_next), stream_f)) { fclose(stream_f); stream_f = NULL; return; }
      stream_next[strcspn(stream_next, "\r\n")] = 0;
      stream_have = 1;
    }
    int n = (int)strlen(stream_next) + 1;
    if (stream_bytes + n > 127 || (stream_head + 1) % 512 == stream_tail) return;
    for (char *c = stream_next; *c; c++) enqueue((unsigned char)*c);
    enqueue('\n');
    stream_inflight[stream_head] = n;
    stream_head = (stream_head + 1) % 512;
    stream_bytes += n;
    stream_sent++;
    stream_have = 0;
  }
}

static avr_cycle_count_t poll_cycles;
static avr_cycle_count_t poll_timer(struct avr_t *a, avr_cycle_count_t when, void *p)
{
  if (!stream_f && stream_head == stream_tail) return 0;
  enqueue('?');
  return when + poll_cycles;
}

int main(int argc, char **argv)
{
  if (argc < 3) { fprintf(stderr, "usage: simrun FIRMWARE.elf SCRIPT [EEPROM]\n"); return 2; }
  elf_firmware_t fw = {0};
  if (elf_read_firmware(argv[1], &fw)) { fprintf(stderr, "simrun: cannot read %s\n", argv[1]); return 1; }
  avr = avr_make_mcu_by_name("atmega328p");
  avr_init(avr);
  avr->frequency = F;
  avr_load_firmware(avr, &fw);
  avr->log = 0;
  static uint8_t ee[1024];
  if (argc > 3) {
    FILE *e = fopen(argv[3], "rb");
    if (e) {
      size_t n = fread(ee, 1, sizeof(ee), e);
      fclose(e);
      avr_eeprom_desc_t d = {.ee = ee, .offset = 0, .size = (uint32_t)n};
      avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
    }
  }
  uint32_t f0 = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &f0);
  f0 &= ~AVR_UART_FLAG_STDIO;
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &f0);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_out, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), xon, NULL);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), xoff, NULL);
  for (int pin = 2; pin <= 7; pin++)
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), pin), pin_change, (void *)(intptr_t)pin);
  // Limit pins idle high (pull-ups, switch open).
  for (int pin = 1; pin <= 3; pin++) avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), pin), 1);
  avr_cycle_timer_register(avr, BYTE_CYCLES, feed, NULL);

  FILE *s = fopen(argv[2], "r");
  if (!s) { fprintf(stderr, "simrun: cannot open %s\n", argv[2]); return 1; }
  // SIMRUN_ISR=ENTRY,RETI[,RETI...] (byte addresses): measure that interrupt
  // handler from its first instruction to its reti, nested interrupts included.
  uint32_t isr_entry = 0, isr_reti[8];
  int n_reti = 0;
  unsigned long long isr_max = 0, isr_n = 0, isr_start = 0, isr_sum = 0;
  if (getenv("SIMRUN_ISR")) {
    char *p = getenv("SIMRUN_ISR"), *e;
    isr_entry = strtoul(p, &e, 16);
    while (*e == ',' && n_reti < 8) { p = e + 1; isr_reti[n_reti++] = strtoul(p, &e, 16); }
  }
  char line[512];
  int state = cpu_Running;
  while (fgets(line, sizeof(line), s)) {
    char *text;
    double ms = strtod(line, &text);
    if (text == line) continue;
    if (*text == ' ') text++;
    text[strcspn(text, "\r\n")] = 0;
    avr_cycle_count_t until = (avr_cycle_count_t)(ms * (F / 1000));
    while (avr->cycle < until && state != cpu_Done && state != cpu_Crashed) {
      state = avr_run(avr);
      stream_pump();
      if (isr_entry) {
        if (avr->pc == isr_entry && !isr_start) isr_start = avr->cycle;
        else if (isr_start) {
          for (int i = 0; i < n_reti; i++) {
            if (avr->pc == isr_reti[i]) {
              // the reti itself is the next instruction (4 cycles)
              unsigned long long d = avr->cycle - isr_start + 4;
              if (d > isr_max) isr_max = d;
              isr_sum += d;
              isr_n++;
              isr_start = 0;
            }
          }
        }
      }
    }
    if (!strcmp(text, "end")) break;
    if (text[0] == '!') { enqueue((unsigned char)strtol(text + 1, NULL, 16)); continue; }
    char sf[300];
    int poll_ms;
    if (sscanf(text, "stream %299s %d", sf, &poll_ms) == 2) {
      stream_f = fopen(sf, "r");
      if (!stream_f) { fprintf(stderr, "simrun: cannot open %s\n", sf); return 1; }
      quiet = 1;
      poll_cycles = (avr_cycle_count_t)poll_ms * (F / 1000);
      if (poll_ms > 0) avr_cycle_timer_register(avr, poll_cycles, poll_timer, NULL);
      continue;
    }
    int ax, on;
    if (sscanf(text, "limit %d %d", &ax, &on) == 2) {
      avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 1 + ax), on ? 0 : 1);
      continue;
    }
    for (char *c = text; *c; c++) enqueue((unsigned char)*c);
    enqueue('\n');
  }
  if (quiet) printf("STREAM sent %ld ok %ld error %ld\n", stream_sent, stream_ok, stream_err);
  printf("\nSTEPS %ld %ld %ld\n", steps[0], steps[1], steps[2]);
  printf("SHORT_PULSES %ld\n", n_short);
  for (int a = 0; a < 3; a++)
    if (steps[a] && last_rise[a] > first_rise[a])
      printf("AXIS %d: %ld steps from cycle %llu to %llu, mean %.0f Hz\n", a, labs(steps[a]), (unsigned long long)first_rise[a],
             (unsigned long long)last_rise[a], (labs(steps[a]) - 1) * (double)F / (double)(last_rise[a] - first_rise[a]));
  if (isr_entry) printf("ISR_CYCLES max %llu mean %.1f n %llu\n", isr_max, isr_n ? (double)isr_sum / isr_n : 0.0, isr_n);
  printf("MIN_PULSE_CYCLES %llu MIN_INTERVAL %llu %llu %llu CYCLE %llu\n", (unsigned long long)min_pulse,
         (unsigned long long)min_interval[0], (unsigned long long)min_interval[1],
         (unsigned long long)min_interval[2], (unsigned long long)avr->cycle);
  if (argc > 3) {
    avr_eeprom_desc_t d = {.ee = NULL, .offset = 0, .size = 1024};
    avr_ioctl(avr, AVR_IOCTL_EEPROM_GET, &d);
    FILE *e = fopen(argv[3], "wb");
    if (e && d.ee) { fwrite(d.ee, 1, 1024, e); fclose(e); }
  }
  return state == cpu_Crashed;
}
