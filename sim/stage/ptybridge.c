/* ptybridge.c: USART0 <-> pseudo-terminal, see ptybridge.h for the policy.
 *
 * Why not simavr's uart_pty part: it runs its own thread that pushes host
 * bytes into the simulated UART whenever that UART last said XON, and a
 * sender that streams while polling `?` saw garbled lines through it. Here
 * one thread does everything and a byte goes in only when the UART's receive
 * FIFO is empty, which is what a wire at 115200 baud gives real silicon. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <sys/inotify.h>
#include <unistd.h>

#include "avr_uart.h"
#include "sim_io.h"
#include "ptybridge.h"

static avr_uart_t *find_uart0(avr_t *avr)
{
    for (avr_io_t *io = avr->io_port; io; io = io->next)
        if (io->kind && !strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0')
            return (avr_uart_t *)io;
    return NULL;
}

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    struct bridge *b = param;

    (void)irq;
    if (b->tx_len == BRIDGE_TXQ) {
        /* nobody reads the pty: like a wire into an unplugged port */
        b->tx_dropped++;
        return;
    }
    b->txq[(b->tx_head + b->tx_len) % BRIDGE_TXQ] = (uint8_t)value;
    b->tx_len++;
    b->tx_bytes++;
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    struct bridge *b = param;
    (void)irq;
    b->xon++;
    if (value) bridge_feed(b);
}

void bridge_feed(struct bridge *b)
{
    avr_uart_t *u = b->uart;
    uint8_t c;

    if (!b->rx_len || b->feeding) return;
    if (!avr_regbit_get(b->avr, u->rxen))
        return; /* receiver off: keep the byte for when it is on */
    if (u->input.read != u->input.write)
        return; /* the previous byte is still on its way or unread */
    c = b->rxq[b->rx_head];
    b->rx_head = (b->rx_head + 1) % BRIDGE_RXQ;
    b->rx_len--;
    b->rx_bytes++;
    b->feeding = 1;
    avr_raise_irq(u->io.irq + UART_IRQ_INPUT, c);
    b->feeding = 0;
}

void bridge_sync_baud(struct bridge *b)
{
    avr_uart_t *u = b->uart;
    avr_t *avr = b->avr;
    uint32_t ubrr = avr_regbit_get(avr, u->ubrrl) | ((uint32_t)avr_regbit_get(avr, u->ubrrh) << 8);
    uint32_t div = avr_regbit_get(avr, u->u2x) ? 8 : 16;
    static const int databits[8] = {5, 6, 7, 8, 8, 8, 8, 9};
    int db = databits[avr_regbit_get(avr, u->ucsz) | (avr_regbit_get(avr, u->ucsz2) << 2)];
    int parity = (avr->data[u->r_ucsrc] >> 4) & 3 ? 1 : 0; /* UPMn1:0 */
    int stop = 1 + avr_regbit_get(avr, u->usbs);
    avr_cycle_count_t cpb =
        (avr_cycle_count_t)div * (ubrr + 1) * (uint32_t)(1 + db + parity + stop);

    if (u->cycles_per_byte != cpb) u->cycles_per_byte = cpb;
    if (avr_regbit_get(avr, u->rxen)) {
        unsigned baud = (unsigned)(avr->frequency / (div * (ubrr + 1)));
        if ((baud < 115200 * 97 / 100 || baud > 115200 * 103 / 100) && baud != b->baud_warned) {
            fprintf(stderr, "stagesim: warning: firmware UART at %u baud, hosts talk at 115200\n",
                    baud);
            b->baud_warned = baud;
        }
    }
}

int bridge_want_read(const struct bridge *b)
{
    return b->rx_len < BRIDGE_RXQ;
}

int bridge_want_write(const struct bridge *b)
{
    return b->tx_len > 0;
}

int bridge_poll_io(struct bridge *b, char *err)
{
    /* host -> avr */
    while (b->rx_len < BRIDGE_RXQ) {
        size_t tail = (b->rx_head + b->rx_len) % BRIDGE_RXQ;
        size_t room = BRIDGE_RXQ - b->rx_len;
        if (room > BRIDGE_RXQ - tail) room = BRIDGE_RXQ - tail;
        ssize_t n = read(b->master, b->rxq + tail, room);
        if (n > 0) {
            b->rx_len += (size_t)n;
            continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno != EAGAIN && errno != EIO) {
            snprintf(err, ERR_LEN, "read(%s): %s", b->path, strerror(errno));
            return -1;
        }
        break;
    }
    /* avr -> host */
    while (b->tx_len) {
        size_t chunk = b->tx_len;
        if (chunk > BRIDGE_TXQ - b->tx_head) chunk = BRIDGE_TXQ - b->tx_head;
        ssize_t n = write(b->master, b->txq + b->tx_head, chunk);
        if (n > 0) {
            b->tx_head = (b->tx_head + (size_t)n) % BRIDGE_TXQ;
            b->tx_len -= (size_t)n;
            continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno != EAGAIN && errno != EIO) {
            snprintf(err, ERR_LEN, "write(%s): %s", b->path, strerror(errno));
            return -1;
        }
        break;
    }
    return 0;
}

int bridge_open(struct bridge *b, avr_t *avr, const char *link, char *err)
{
    struct termios tio;
    uint32_t flags = 0;

    memset(b, 0, sizeof(*b));
    b->avr = avr;
    b->master = b->slave = b->ino = -1;
    b->uart = find_uart0(avr);
    if (!b->uart) {
        snprintf(err, ERR_LEN, "bridge_open: %s has no USART0", avr->mmcu);
        return -1;
    }
    /* no "poll sleep" (it usleeps inside the simulation), no stdio echo
	 * (it prints the firmware's lines on our stdout) */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);

    b->master = posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (b->master < 0) {
        snprintf(err, ERR_LEN, "posix_openpt: %s", strerror(errno));
        goto fail;
    }
    if (grantpt(b->master) < 0 || unlockpt(b->master) < 0 ||
        ptsname_r(b->master, b->path, sizeof(b->path)) != 0) {
        snprintf(err, ERR_LEN, "unlockpt: %s", strerror(errno));
        goto fail;
    }
    /* Keep the slave open ourselves: the firmware's banner waits in the
	 * line discipline for the first client, and a client closing the port
	 * never hangs the master up. */
    b->slave = open(b->path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (b->slave < 0) {
        snprintf(err, ERR_LEN, "open(%s): %s", b->path, strerror(errno));
        goto fail;
    }
    if (tcgetattr(b->slave, &tio) < 0) {
        snprintf(err, ERR_LEN, "tcgetattr(%s): %s", b->path, strerror(errno));
        goto fail;
    }
    /* raw: no echo of the firmware's output back into its input, no CR/LF
	 * translation; TCSANOW, never TCSAFLUSH, so nothing already queued is lost */
    cfmakeraw(&tio);
    cfsetispeed(&tio, B115200);
    cfsetospeed(&tio, B115200);
    if (tcsetattr(b->slave, TCSANOW, &tio) < 0) {
        snprintf(err, ERR_LEN, "tcsetattr(%s): %s", b->path, strerror(errno));
        goto fail;
    }
    if (link && *link) {
        if (strlen(link) >= sizeof(b->link)) {
            snprintf(err, ERR_LEN, "--link %s: path too long", link);
            goto fail;
        }
        unlink(link);
        if (symlink(b->path, link) < 0) {
            snprintf(err, ERR_LEN, "symlink(%s): %s", link, strerror(errno));
            goto fail;
        }
        strcpy(b->link, link);
    }
    {
        avr_uart_t *u = b->uart;
        avr_irq_register_notify(u->io.irq + UART_IRQ_OUTPUT, uart_out_hook, b);
        avr_irq_register_notify(u->io.irq + UART_IRQ_OUT_XON, uart_xon_hook, b);
    }
    return 0;
fail:
    if (b->slave >= 0) close(b->slave);
    if (b->master >= 0) close(b->master);
    b->slave = b->master = -1;
    return -1;
}

int bridge_watch_opens(struct bridge *b, char *err)
{
    b->ino = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
    if (b->ino < 0) {
        snprintf(err, ERR_LEN, "inotify_init1: %s", strerror(errno));
        return -1;
    }
    /* our own descriptor on the slave is already open: only others count */
    if (inotify_add_watch(b->ino, b->path, IN_OPEN | IN_CLOSE) < 0) {
        snprintf(err, ERR_LEN, "inotify_add_watch(%s): %s", b->path, strerror(errno));
        close(b->ino);
        b->ino = -1;
        return -1;
    }
    return 0;
}

int bridge_check_opens(struct bridge *b)
{
    char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
    int reset = 0;
    ssize_t n;

    if (b->ino < 0) return 0;
    while ((n = read(b->ino, buf, sizeof(buf))) > 0) {
        for (char *p = buf; p < buf + n;
             p += sizeof(struct inotify_event) + ((struct inotify_event *)p)->len) {
            const struct inotify_event *e = (const struct inotify_event *)p;
            if (e->mask & IN_OPEN) {
                b->opens++;
                /* the first client finds the chip just powered up (its
				 * banner waits in the pty): as if it had been there */
                if (b->clients++ == 0 && b->opens > 1) reset = 1;
            }
            /* DTR drops when the last client closes. (A real port
			 * keeps it up when HUPCL is off, but a pty starts with
			 * HUPCL off and no client sets it: not modelled.) */
            if ((e->mask & IN_CLOSE) && b->clients > 0) b->clients--;
        }
    }
    if (reset) b->auto_resets++;
    return reset;
}

void bridge_flush(struct bridge *b)
{
    b->rx_head = b->rx_len = 0;
    b->tx_head = b->tx_len = 0;
    tcflush(b->slave, TCIFLUSH);  /* firmware output the client has not read */
    tcflush(b->master, TCIFLUSH); /* client bytes the bridge has not read */
}

void bridge_close(struct bridge *b)
{
    if (b->link[0]) unlink(b->link);
    if (b->ino >= 0) close(b->ino);
    if (b->slave >= 0) close(b->slave);
    if (b->master >= 0) close(b->master);
    b->slave = b->master = b->ino = -1;
    b->link[0] = 0;
}
