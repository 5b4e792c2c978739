/* ptybridge.h: the firmware's USART0 on a pseudo-terminal.
 *
 * Host -> AVR: bytes read from the pty master wait in a queue and go into
 * the simulated UART one at a time, only when its receive FIFO is empty, so
 * each byte arrives one character time after the firmware took the previous
 * one, as on a wire at the configured baud rate, and none is ever dropped by
 * the simulator. AVR -> host: every byte the firmware transmits is written to
 * the master; when nobody reads the pty the bytes wait in a bounded queue.
 * All of it runs in the simulation thread. */
#ifndef PTYBRIDGE_H
#define PTYBRIDGE_H

#include <stddef.h>
#include <stdint.h>
#include "sim_avr.h"
#include "err.h" /* ERR_LEN: err[] buffers */

#define BRIDGE_RXQ 4096  /* host -> avr bytes read ahead from the pty */
#define BRIDGE_TXQ 65536 /* avr -> host bytes waiting for the pty */

struct bridge {
    avr_t *avr;
    void *uart;        /* avr_uart_t of USART0 */
    int master, slave; /* slave kept open: no EIO/hangup between clients */
    char path[256];
    char link[256]; /* optional symlink to path, "" if none */
    uint8_t rxq[BRIDGE_RXQ];
    size_t rx_head, rx_len;
    uint8_t txq[BRIDGE_TXQ];
    size_t tx_head, tx_len;
    uint64_t rx_bytes, tx_bytes, tx_dropped, xon;
    int feeding;          /* guards against re-entry from the XON hook */
    unsigned baud_warned; /* last baud rate we warned about */
    /* auto-reset: a pty has no DTR, so opens of the slave are watched */
    int ino;     /* inotify descriptor on the slave, -1: off */
    int clients; /* descriptors other processes hold on the slave */
    uint64_t opens, auto_resets;
};

/* Open the pty (raw, no flush), hook USART0. link may be NULL. */
int bridge_open(struct bridge *b, avr_t *avr, const char *link, char *err);

/* Read what the host wrote (non-blocking) and push queued output. Main loop. */
int bridge_poll_io(struct bridge *b, char *err);

/* Hand the next queued byte to the UART if it can take one. Main loop and XON hook. */
void bridge_feed(struct bridge *b);

/* 1 if there is room to read more host bytes, for the poll(2) set. */
int bridge_want_read(const struct bridge *b);

/* 1 if output waits for the pty to drain. */
int bridge_want_write(const struct bridge *b);

/* Recompute the UART's character time from UBRR, U2X and the frame format
 * (simavr 1.6 computes it only when UBRR is written, so firmware that sets
 * U2X afterwards, as grbl does, would receive at half speed, and it always
 * counts a parity bit). Main loop, cheap. */
void bridge_sync_baud(struct bridge *b);

/* Auto-reset, as DTR does on an Uno: watch the slave for opens by other
 * processes (inotify; opening the port is the one thing no client can skip,
 * and what raises DTR on a USB serial adapter). Main loop. */
int bridge_watch_opens(struct bridge *b, char *err);

/* Take the open/close events; 1 when a client opened the port while no
 * other had it open (DTR rises: the Uno resets), except the very first
 * client, which finds the chip just powered up. Main loop. */
int bridge_check_opens(struct bridge *b);

/* Forget bytes of the previous session in both directions (queued here and
 * in the pty), as a board held in reset neither hears nor says anything. */
void bridge_flush(struct bridge *b);

/* Close the pty and remove the link. */
void bridge_close(struct bridge *b);

#endif
