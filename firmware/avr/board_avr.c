// ATmega328P port of the board interface: UART, step timer, pins, EEPROM,
// watchdog, millisecond clock.
#include <avr/io.h>
#include <avr/interrupt.h>
#include <avr/eeprom.h>
#include <avr/wdt.h>
#include "pins.h"
#include "../core/board.h"
#include "../core/config.h"
#include "../core/serial.h"   // serial_rx_isr, serial_tx_isr
#include "../core/stepper.h"  // st_isr
#include "../core/limits.h"   // limits_pin_change_isr

static volatile uint32_t millis_count;
static uint8_t step_idle_port;   // STEP_PORT bits with no pulse (after $2 inversion)
static uint8_t pulse_ticks[4];   // OCR1B per prescaler code 1..3
static uint8_t enable_invert;
static uint8_t reset_flags;
static uint8_t step_prescale;

// Read and clear the reset cause before the watchdog (still armed after a
// watchdog reset, at 16 ms) can fire again.
uint8_t mcusr_mirror __attribute__((section(".noinit")));
void board_early_init(void) __attribute__((naked, used, section(".init3")));
void board_early_init(void)
{
  mcusr_mirror = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

// Stack guard: two bytes just past static data; the stack grows down to them.
extern uint8_t __bss_end;
#define STACK_CANARY 0xa5

uint8_t board_stack_ok(void)
{
  return (&__bss_end)[0] == STACK_CANARY && (&__bss_end)[1] == STACK_CANARY;
}

void board_init(void)
{
  reset_flags = mcusr_mirror;
  (&__bss_end)[0] = STACK_CANARY;
  (&__bss_end)[1] = STACK_CANARY;

  STEP_DDR |= STEP_MASK;
  DIR_DDR |= DIR_MASK;
  ENABLE_PORT |= (1 << ENABLE_BIT);   // drivers off until a move
  ENABLE_DDR |= (1 << ENABLE_BIT);
  LIMIT_DDR &= ~LIMIT_MASK;
  LIMIT_PORT |= LIMIT_MASK;           // pull-ups: switches close to ground

  // UART: 115200 8N1, U2X (0.8 % error at 16 MHz, as GRBL and Optiboot).
  UCSR0A = (1 << U2X0);
  UBRR0 = (F_CPU / (8UL * BAUD_RATE)) - 1;
  UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);
  UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);

  // Timer1: step timer, CTC on OCR1A, stopped.
  TCCR1A = 0;
  TCCR1B = (1 << WGM12);
  TIMSK1 = 0;

  // Timer2: 1 kHz clock for millis (CTC, /64, OCR2A = 249: never 0).
  TCCR2A = (1 << WGM21);
  OCR2A = (F_CPU / 64 / 1000) - 1;
  TIMSK2 = (1 << OCIE2A);
  TCCR2B = (1 << CS22);

  wdt_enable(WDTO_500MS);
  sei();
}

uint8_t board_reset_cause_watchdog(void)
{
  return (reset_flags & (1 << WDRF)) != 0;
}

uint8_t board_irq_save(void)
{
  uint8_t s = SREG;
  cli();
  return s;
}

void board_irq_restore(uint8_t flag)
{
  SREG = flag;
}

void board_irq_enable(void)
{
  sei();
}

void board_irq_disable(void)
{
  cli();
}

void board_idle(void)
{
  wdt_reset();
}

void board_watchdog_kick(void)
{
  wdt_reset();
}

uint32_t board_millis(void)
{
  uint8_t s = SREG;
  cli();
  uint32_t m = millis_count;
  SREG = s;
  return m;
}

ISR(TIMER2_COMPA_vect)
{
  millis_count++;
  limits_tick_isr();   // hard-limit debounce
}

void board_uart_tx_kick(void)
{
  UCSR0B |= (1 << UDRIE0);
}

ISR(USART_RX_vect)
{
  uint8_t c = UDR0;
  serial_rx_isr(c);
}

ISR(USART_UDRE_vect)
{
  int16_t c = serial_tx_isr();
  if (c < 0) UCSR0B &= ~(1 << UDRIE0);
  else UDR0 = (uint8_t)c;
}

uint8_t board_eeprom_read(uint16_t addr)
{
  return eeprom_read_byte((const uint8_t *)addr);
}

void board_eeprom_write(uint16_t addr, uint8_t v)
{
  wdt_reset();
  eeprom_update_byte((uint8_t *)addr, v);  // waits for the previous write (3.3 ms)
}

void board_stepper_enable(uint8_t on)
{
  // The shield's enable is active low; $4 inverts. (Single-bit cbi/sbi: atomic.)
  if (on ^ enable_invert) ENABLE_PORT &= ~(1 << ENABLE_BIT);
  else ENABLE_PORT |= (1 << ENABLE_BIT);
}

void board_stepper_config(uint8_t pulse_us, uint8_t step_idle_bits, uint8_t invert_enable)
{
  uint32_t cycles = (uint32_t)pulse_us * (F_CPU / 1000000UL);
  pulse_ticks[1] = cycles > 255 ? 255 : cycles;
  pulse_ticks[2] = ((cycles + 7) >> 3) + 1;
  pulse_ticks[3] = ((cycles + 63) >> 6) + 1;
  step_idle_port = (step_idle_bits << STEP_SHIFT) & STEP_MASK;
  enable_invert = invert_enable;
  uint8_t s = SREG;
  cli();
  STEP_PORT = (STEP_PORT & ~STEP_MASK) | step_idle_port;
  SREG = s;
}

void board_step_write(uint8_t axis_bits)
{
  uint8_t s = SREG;   // the step ISR calls this with interrupts off; st_reset does not
  cli();
  STEP_PORT = (STEP_PORT & ~STEP_MASK) | ((axis_bits << STEP_SHIFT) & STEP_MASK);
  SREG = s;
}

void board_dir_write(uint8_t axis_bits)
{
  // Step and direction share PORTD: the pulse-end interrupt must not land
  // inside this read-modify-write, or the old step level is written back.
  uint8_t s = SREG;
  cli();
  DIR_PORT = (DIR_PORT & ~DIR_MASK) | ((axis_bits << DIR_SHIFT) & DIR_MASK);
  SREG = s;
}

void board_step_pulse_start(void)
{
  // The pulse ends $0 us after the pins were set, however late the step
  // interrupt started (another interrupt may have delayed it): measured from
  // the counter, never from the compare match. The counter is only read.
  uint16_t end = TCNT1 + pulse_ticks[step_prescale];
  uint16_t top = OCR1A;
  if (end >= top) end = top - 1;   // only for periods shorter than the pulse (prevented by the planner)
  if (end == 0) end = 1;           // a compare of 0 never fires in simavr
  OCR1B = end;
  TIFR1 = (1 << OCF1B);            // a match of the previous value must not end this pulse
}

void board_step_timer_set(uint16_t ticks, uint8_t prescale)
{
  // Called right after a compare match (TCNT1 small), so the new period is
  // never below the counter.
  OCR1A = ticks;
  if (prescale != step_prescale) {
    step_prescale = prescale;
    if (TCCR1B & 7) TCCR1B = (1 << WGM12) | prescale;
  }
}

void board_step_timer_start(void)
{
  TCNT1 = 0;  // clock is stopped here; simavr also zeroes it when the clock starts
  TIFR1 = (1 << OCF1A) | (1 << OCF1B);
  TIMSK1 = (1 << OCIE1A) | (1 << OCIE1B);
  TCCR1B = (1 << WGM12) | step_prescale;
}

void board_step_timer_stop(void)
{
  // Stop the step tick now; the clock runs on until the pulse-end compare
  // has returned the step pins to idle (that ISR stops the clock).
  TIMSK1 &= ~(1 << OCIE1A);
}

ISR(TIMER1_COMPA_vect)
{
  st_isr();
}

ISR(TIMER1_COMPB_vect)
{
  STEP_PORT = (STEP_PORT & ~STEP_MASK) | step_idle_port;
  if (!(TIMSK1 & (1 << OCIE1A))) {
    TCCR1B = (1 << WGM12);   // stopped: clock off
    TIMSK1 = 0;
  }
}

uint8_t board_limits_read(void)
{
  return (LIMIT_PIN & LIMIT_MASK) >> LIMIT_SHIFT;
}

void board_limits_irq(uint8_t on)
{
  if (on) {
    LIMIT_PCMSK |= LIMIT_MASK;
    PCICR |= (1 << LIMIT_PCIE);
  } else {
    PCICR &= ~(1 << LIMIT_PCIE);
  }
}

ISR(PCINT0_vect)
{
  limits_pin_change_isr();
}
