/*
 * testfw: a tiny ATmega328P program that exercises the simulated stage
 * without the real firmware. Built by sim/stage/Makefile (target testfw).
 *
 * Serial 115200 8N1, interrupt-driven receive into a 128-byte ring so that a
 * lost byte shows as a gap in the echo. Commands (one byte each):
 *   a b c   one step on X/Y/Z, DIR low  (positive)
 *   A B C   one step on X/Y/Z, DIR high (negative)
 *   e d     enable / disable the drivers (PB0 low / high)
 *   l       print "L" and the three limit inputs PB1..PB3 as 0/1 digits
 *   w<v>    store byte v at EEPROM address 0;  r  print "R" and that byte
 *   t<n>    burst of (n - '0') * 1000 X steps from Timer1 at 20 kHz
 *   z       OCR1A = 0 for 2 ms (the simavr CTC trap; stagesim must warn)
 *   p       print "P" and the count of limit pin-change interrupts, 3 digits
 * Every other byte is echoed.
 */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <stdint.h>

#define RX_SIZE 128

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint16_t burst_left;
static volatile uint16_t pin_changes;

ISR(PCINT0_vect)
{
    pin_changes++;
}

ISR(USART_RX_vect)
{
    uint8_t c = UDR0;
    uint8_t next = (uint8_t)((rx_head + 1) % RX_SIZE);
    if (next != rx_tail) {
        rx_buf[rx_head] = c;
        rx_head = next;
    }
}

ISR(TIMER1_COMPA_vect)
{
    if (burst_left) {
        PORTD |= _BV(PD2);
        __builtin_avr_delay_cycles(40); /* 2.5 us pulse */
        PORTD &= ~_BV(PD2);
        burst_left--;
    }
}

static void uart_put(uint8_t c)
{
    while (!(UCSR0A & _BV(UDRE0)))
        ;
    UDR0 = c;
}

static void uart_puts(const char *s)
{
    while (*s) uart_put((uint8_t)*s++);
}

static int uart_get(void)
{
    uint8_t c;
    if (rx_head == rx_tail) return -1;
    c = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1) % RX_SIZE);
    return c;
}

static uint8_t uart_wait(void)
{
    int c;
    while ((c = uart_get()) < 0)
        ;
    return (uint8_t)c;
}

static void step(uint8_t axis, uint8_t negative)
{
    uint8_t dir = (uint8_t)_BV(PD5 + axis);
    if (negative)
        PORTD |= dir;
    else
        PORTD &= (uint8_t)~dir;
    __builtin_avr_delay_cycles(16);
    PORTD |= (uint8_t)_BV(PD2 + axis);
    __builtin_avr_delay_cycles(40);
    PORTD &= (uint8_t)~_BV(PD2 + axis);
    __builtin_avr_delay_cycles(40);
}

int main(void)
{
    DDRD = 0xfc; /* STEP PD2..4, DIR PD5..7 */
    PORTD = 0;
    DDRB = _BV(PB0);                                   /* enable; PB1..3 limit inputs */
    PORTB = _BV(PB0) | _BV(PB1) | _BV(PB2) | _BV(PB3); /* disabled, pull-ups */

    UBRR0 = 16; /* 115200 with U2X at 16 MHz */
    UCSR0A = _BV(U2X0);
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    OCR1A = 799; /* 16 MHz / 800 = 20 kHz */
    TCCR1B = _BV(WGM12) | _BV(CS10);
    TIMSK1 = _BV(OCIE1A);
    PCMSK0 = _BV(PCINT1) | _BV(PCINT2) | _BV(PCINT3);
    PCICR = _BV(PCIE0);
    sei();

    uart_puts("testfw ready\r\n");
    for (;;) {
        uint8_t c = uart_wait();
        switch (c) {
        case 'a':
        case 'b':
        case 'c': step((uint8_t)(c - 'a'), 0); break;
        case 'A':
        case 'B':
        case 'C': step((uint8_t)(c - 'A'), 1); break;
        case 'e': PORTB &= (uint8_t)~_BV(PB0); break;
        case 'd': PORTB |= _BV(PB0); break;
        case 'l':
            uart_put('L');
            uart_put((PINB & _BV(PB1)) ? '1' : '0');
            uart_put((PINB & _BV(PB2)) ? '1' : '0');
            uart_put((PINB & _BV(PB3)) ? '1' : '0');
            break;
        case 'w': eeprom_update_byte((uint8_t *)0, uart_wait()); break;
        case 'r':
            uart_put('R');
            uart_put(eeprom_read_byte((const uint8_t *)0));
            break;
        case 'p': {
            uint16_t n;
            cli();
            n = pin_changes;
            sei();
            uart_put('P');
            uart_put((uint8_t)('0' + n / 100 % 10));
            uart_put((uint8_t)('0' + n / 10 % 10));
            uart_put((uint8_t)('0' + n % 10));
            break;
        }
        case 'z':
            OCR1A = 0;
            __builtin_avr_delay_cycles(32000);
            OCR1A = 799;
            uart_put('Z');
            break;
        case 't': {
            uint16_t n = (uint16_t)(uart_wait() - '0') * 1000u;
            cli();
            burst_left = n;
            sei();
            break;
        }
        default: uart_put(c);
        }
    }
}
