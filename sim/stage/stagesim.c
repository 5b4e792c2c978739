/* stagesim: the spherepose stage simulated. Runs the stage firmware ELF (the
 * same file one would flash) on simavr's atmega328p, puts USART0 on a
 * pseudo-terminal, integrates the STEP/DIR pulses into the true mechanical
 * angles, models the limit switches, keeps the EEPROM in a file, and serves
 * the angles on a Unix socket. Interface: docs/interfaces.md; manual:
 * docs/stagesim.md.
 *
 * One thread does everything: run a slice of instructions, then service the
 * pty and the socket. Callbacks from simavr (pins, UART) therefore never race
 * with the I/O code. */
#define _GNU_SOURCE
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_hex.h"
#include "sim_core.h"
#include "avr_uart.h"

#include "eefile.h"
#include "ptybridge.h"
#include "stage.h"
#include "statesrv.h"

#define SLICE         2000 /* instructions between two looks at the outside */
#define EE_SAVE_EVERY 1.0  /* seconds of wall time between EEPROM checks */
#define MAX_LAG       0.25 /* wall seconds behind simulated time before we stop catching up */

struct options {
    const char *elf;
    const char *mcu;
    unsigned freq;
    const char *eeprom;
    const char *socket;
    const char *link;
    double steps_per_deg[STAGE_AXES];
    double start[STAGE_AXES];
    int limit_on[STAGE_AXES];
    double limit[STAGE_AXES];
    int limit_dir[STAGE_AXES];
    double limit_width, limit_hyst;
    int limit_bounce;
    double limit_bounce_us;
    int dir_invert, step_invert;
    int realtime;
    int verbose;
    int auto_reset;
    const char *bootloader;
};

static volatile sig_atomic_t stop_requested;
static int verbose_level;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

/* simavr's messages go to stderr: stdout carries only our PTY/STATE lines */
static void logger(avr_t *avr, const int level, const char *fmt, va_list ap)
{
    (void)avr;
    if (level > verbose_level) return;
    fputs("stagesim: simavr: ", stderr);
    vfprintf(stderr, fmt, ap);
}

static void sleep_none(avr_t *avr, avr_cycle_count_t how_long)
{
    /* pacing is ours (see run loop); simavr's own usleep would stall the pty */
    (void)avr;
    (void)how_long;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void usage(FILE *f)
{
    fprintf(
        f,
        "usage: stagesim [options] FIRMWARE.elf\n"
        "       stagesim [options] --bootloader optiboot_atmega328.hex [FIRMWARE.elf]\n"
        "  --state-socket PATH   serve the stage state on a Unix socket (see docs/interfaces.md)\n"
        "  --eeprom FILE         EEPROM image: loaded at start when present, saved on change and "
        "on exit\n"
        "  --link PATH           symlink PATH to the pty\n"
        "  --steps-per-deg X,Y,Z motor steps per degree (default 800,800,800; one value for all)\n"
        "  --start X,Y,Z         mechanical angles at power-up in degrees (default 0,0,0)\n"
        "  --limits X,Y,Z        limit switch positions in degrees ('none' for no switch; default "
        "none)\n"
        "  --limit-x/-y/-z DEG   one switch position ('none' to remove it)\n"
        "  --limit-dir D,D,D     side each switch closes on: + (angle >= position) or - (default "
        "+,+,+)\n"
        "  --limit-width DEG     switch stays pressed this far past its position, then releases "
        "(default 0: forever)\n"
        "  --limit-hyst DEG      travel back needed to release a pressed switch (default 0.05)\n"
        "  --limit-bounce N      contact bounces (open/close pairs) after each switch transition "
        "(default 0)\n"
        "  --limit-bounce-us US  time between two bounces (default 200)\n"
        "  --dir-invert MASK     bit i set: DIR high is the positive direction on axis i (default "
        "0, as grbl)\n"
        "  --step-invert MASK    bit i set: the STEP pulse is active low on axis i (default 0)\n"
        "  --no-auto-reset       opening the port does not reset the chip (default: it does, as "
        "DTR on an Uno)\n"
        "  --bootloader HEX      boot this bootloader (Optiboot) first, fuses as on the Uno; "
        "FIRMWARE.elf is then\n"
        "                        optional: without it the flash is blank until avrdude programs it "
        "over the pty\n"
        "  --realtime            pace simulated time to wall time (default)\n"
        "  --fast                run as fast as the host allows\n"
        "  --mcu NAME            MCU when the ELF names none (default atmega328p)\n"
        "  --freq HZ             clock when the ELF names none (default 16000000)\n"
        "  -v, --verbose         more simavr messages on stderr (repeat for more)\n"
        "  -h, --help            this text\n"
        "stdout: 'PTY <path>' then, with --state-socket, 'STATE <path>'. SIGTERM/SIGINT stop "
        "it.\n");
}

static int parse_triple(const char *opt, const char *arg, double out[STAGE_AXES], int none_ok,
                        int on[STAGE_AXES], char *err)
{
    char buf[256], *save = NULL, *tok;
    int n = 0;

    if (strlen(arg) >= sizeof(buf)) {
        snprintf(err, ERR_LEN, "%s %s: too long", opt, arg);
        return -1;
    }
    strcpy(buf, arg);
    for (tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
        char *end;
        if (n == STAGE_AXES) {
            snprintf(err, ERR_LEN, "%s %s: more than 3 values", opt, arg);
            return -1;
        }
        if (none_ok && !strcmp(tok, "none")) {
            on[n++] = 0;
            continue;
        }
        errno = 0;
        double v = strtod(tok, &end);
        if (errno || end == tok || *end || !isfinite(v)) {
            snprintf(err, ERR_LEN, "%s %s: '%s' is not a number", opt, arg, tok);
            return -1;
        }
        if (on) on[n] = 1;
        out[n++] = v;
    }
    if (n == 1) {
        for (int i = 1; i < STAGE_AXES; i++) {
            out[i] = out[0];
            if (on) on[i] = on[0];
        }
    } else if (n != STAGE_AXES) {
        snprintf(err, ERR_LEN, "%s %s: give one value or three (X,Y,Z)", opt, arg);
        return -1;
    }
    return 0;
}

static int parse_number(const char *opt, const char *arg, double *out, char *err)
{
    char *end;
    errno = 0;
    *out = strtod(arg, &end);
    if (errno || end == arg || *end || !isfinite(*out)) {
        snprintf(err, ERR_LEN, "%s %s: not a number", opt, arg);
        return -1;
    }
    return 0;
}

static int parse_options(int argc, char **argv, struct options *o, char *err)
{
    enum {
        O_SOCKET = 256,
        O_EEPROM,
        O_LINK,
        O_SPD,
        O_START,
        O_LIMITS,
        O_LX,
        O_LY,
        O_LZ,
        O_LDIR,
        O_LWIDTH,
        O_LHYST,
        O_LBOUNCE,
        O_LBOUNCEUS,
        O_DIRINV,
        O_STEPINV,
        O_REALTIME,
        O_FAST,
        O_MCU,
        O_FREQ,
        O_NOAUTORESET,
        O_AUTORESET,
        O_BOOT
    };
    static const struct option longopts[] = {{"state-socket", required_argument, 0, O_SOCKET},
                                             {"eeprom", required_argument, 0, O_EEPROM},
                                             {"link", required_argument, 0, O_LINK},
                                             {"steps-per-deg", required_argument, 0, O_SPD},
                                             {"start", required_argument, 0, O_START},
                                             {"limits", required_argument, 0, O_LIMITS},
                                             {"limit-x", required_argument, 0, O_LX},
                                             {"limit-y", required_argument, 0, O_LY},
                                             {"limit-z", required_argument, 0, O_LZ},
                                             {"limit-dir", required_argument, 0, O_LDIR},
                                             {"limit-width", required_argument, 0, O_LWIDTH},
                                             {"limit-hyst", required_argument, 0, O_LHYST},
                                             {"limit-bounce", required_argument, 0, O_LBOUNCE},
                                             {"limit-bounce-us", required_argument, 0, O_LBOUNCEUS},
                                             {"dir-invert", required_argument, 0, O_DIRINV},
                                             {"step-invert", required_argument, 0, O_STEPINV},
                                             {"realtime", no_argument, 0, O_REALTIME},
                                             {"no-auto-reset", no_argument, 0, O_NOAUTORESET},
                                             {"auto-reset", no_argument, 0, O_AUTORESET},
                                             {"bootloader", required_argument, 0, O_BOOT},
                                             {"fast", no_argument, 0, O_FAST},
                                             {"mcu", required_argument, 0, O_MCU},
                                             {"freq", required_argument, 0, O_FREQ},
                                             {"verbose", no_argument, 0, 'v'},
                                             {"help", no_argument, 0, 'h'},
                                             {0, 0, 0, 0}};
    int c;
    double v;

    memset(o, 0, sizeof(*o));
    o->mcu = "atmega328p";
    o->freq = 16000000;
    o->realtime = 1;
    o->auto_reset = 1;
    o->limit_hyst = 0.05;
    o->limit_bounce_us = 200;
    for (int i = 0; i < STAGE_AXES; i++) {
        o->steps_per_deg[i] = 800.0;
        o->limit_dir[i] = 1;
    }
    while ((c = getopt_long(argc, argv, "vh", longopts, NULL)) != -1) {
        switch (c) {
        case O_SOCKET: o->socket = optarg; break;
        case O_EEPROM: o->eeprom = optarg; break;
        case O_LINK: o->link = optarg; break;
        case O_SPD:
            if (parse_triple("--steps-per-deg", optarg, o->steps_per_deg, 0, NULL, err) < 0)
                return -1;
            for (int i = 0; i < STAGE_AXES; i++)
                if (o->steps_per_deg[i] <= 0) {
                    snprintf(err, ERR_LEN, "--steps-per-deg %s: must be > 0", optarg);
                    return -1;
                }
            break;
        case O_START:
            if (parse_triple("--start", optarg, o->start, 0, NULL, err) < 0) return -1;
            break;
        case O_LIMITS:
            if (parse_triple("--limits", optarg, o->limit, 1, o->limit_on, err) < 0) return -1;
            break;
        case O_LX:
        case O_LY:
        case O_LZ: {
            int i = c - O_LX;
            if (!strcmp(optarg, "none")) {
                o->limit_on[i] = 0;
                break;
            }
            static const char *names[STAGE_AXES] = {"--limit-x", "--limit-y", "--limit-z"};
            if (parse_number(names[i], optarg, &o->limit[i], err) < 0) return -1;
            o->limit_on[i] = 1;
            break;
        }
        case O_LDIR: {
            char buf[64], *save = NULL, *tok;
            int n = 0;
            snprintf(buf, sizeof(buf), "%s", optarg);
            for (tok = strtok_r(buf, ",", &save); tok; tok = strtok_r(NULL, ",", &save)) {
                if (n == STAGE_AXES || (strcmp(tok, "+") && strcmp(tok, "-"))) {
                    snprintf(err, ERR_LEN, "--limit-dir %s: give +/- for X,Y,Z", optarg);
                    return -1;
                }
                o->limit_dir[n++] = tok[0] == '-' ? -1 : 1;
            }
            if (n == 1)
                o->limit_dir[1] = o->limit_dir[2] = o->limit_dir[0];
            else if (n != STAGE_AXES) {
                snprintf(err, ERR_LEN, "--limit-dir %s: give +/- for X,Y,Z", optarg);
                return -1;
            }
            break;
        }
        case O_LWIDTH:
            if (parse_number("--limit-width", optarg, &o->limit_width, err) < 0) return -1;
            break;
        case O_LHYST:
            if (parse_number("--limit-hyst", optarg, &o->limit_hyst, err) < 0) return -1;
            break;
        case O_LBOUNCE:
            if (parse_number("--limit-bounce", optarg, &v, err) < 0) return -1;
            if (v < 0 || v > 100 || v != (int)v) {
                snprintf(err, ERR_LEN, "--limit-bounce %s: a count 0..100", optarg);
                return -1;
            }
            o->limit_bounce = (int)v;
            break;
        case O_LBOUNCEUS:
            if (parse_number("--limit-bounce-us", optarg, &o->limit_bounce_us, err) < 0) return -1;
            if (o->limit_bounce_us < 1 || o->limit_bounce_us > 100000) {
                snprintf(err, ERR_LEN, "--limit-bounce-us %s: 1..100000", optarg);
                return -1;
            }
            break;
        case O_DIRINV:
        case O_STEPINV: {
            char *end;
            long m = strtol(optarg, &end, 0);
            if (end == optarg || *end || m < 0 || m > 7) {
                snprintf(err, ERR_LEN, "%s %s: a mask 0..7",
                         c == O_DIRINV ? "--dir-invert" : "--step-invert", optarg);
                return -1;
            }
            if (c == O_DIRINV)
                o->dir_invert = (int)m;
            else
                o->step_invert = (int)m;
            break;
        }
        case O_REALTIME: o->realtime = 1; break;
        case O_NOAUTORESET: o->auto_reset = 0; break;
        case O_AUTORESET: o->auto_reset = 1; break;
        case O_BOOT: o->bootloader = optarg; break;
        case O_FAST: o->realtime = 0; break;
        case O_MCU: o->mcu = optarg; break;
        case O_FREQ:
            if (parse_number("--freq", optarg, &v, err) < 0) return -1;
            if (v < 1000 || v > 100e6) {
                snprintf(err, ERR_LEN, "--freq %s: out of range", optarg);
                return -1;
            }
            o->freq = (unsigned)v;
            break;
        case 'v': o->verbose++; break;
        case 'h': usage(stdout); exit(0);
        default: snprintf(err, ERR_LEN, "bad option (see --help)"); return -1;
        }
    }
    if (optind == argc && o->bootloader)
        return 0; /* a blank chip with its bootloader: avrdude fills it */
    if (optind != argc - 1) {
        snprintf(err, ERR_LEN, "need exactly one FIRMWARE.elf (see --help)");
        return -1;
    }
    o->elf = argv[optind];
    return 0;
}

/* A reset sets SP to RAMEND on silicon, and bootloaders built without C
 * start-up code (Optiboot) rely on it; simavr 1.6 leaves SP at 0. */
static void (*core_reset)(avr_t *avr);

static void set_sp_ramend(avr_t *avr)
{
    avr->data[0x5d] = (uint8_t)(avr->ramend & 0xff); /* SPL */
    avr->data[0x5e] = (uint8_t)(avr->ramend >> 8);   /* SPH */
}

/* MCUSR: the cause of the last reset, which bootloaders and the firmware read */
#define REG_MCUSR   0x54
#define MCUSR_PORF  0x01
#define MCUSR_EXTRF 0x02

/* The RESET pin pulled low (the button, or DTR through the Uno's capacitor):
 * the MCU restarts with EXTRF set, the motors stay where they are. */
static void external_reset(avr_t *avr, struct stage *stage)
{
    avr_reset(avr);
    avr->data[REG_MCUSR] |= MCUSR_EXTRF;
    stage_sync_limits(stage);
}

static void reset_hook(avr_t *avr)
{
    if (core_reset) core_reset(avr);
    set_sp_ramend(avr);
}

/* The Uno's fuses: low 0xFF (16 MHz crystal), high 0xDE (BOOTRST on, boot
 * section of 256 words at 0x7E00, SPIEN), extended 0xFD (brown-out 2.7 V). */
#define UNO_LFUSE      0xff
#define UNO_HFUSE      0xde
#define UNO_EFUSE      0xfd
#define UNO_BOOT_START 0x7e00 /* bytes; BOOTSZ = 11 in UNO_HFUSE */

/* Put an Intel HEX bootloader into the boot section and start there on every
 * reset, as BOOTRST does (simavr has no fuse logic of its own; its SPM
 * support lets the bootloader write the application section). */
static int load_bootloader(avr_t *avr, const char *path, char *err)
{
    ihex_chunk_p chunks = NULL;
    int n = read_ihex_chunks(path, &chunks);

    if (n <= 0) {
        snprintf(err, ERR_LEN, "--bootloader %s: not a readable Intel HEX file", path);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        if (chunks[i].baseaddr < UNO_BOOT_START ||
            chunks[i].baseaddr + chunks[i].size > avr->flashend + 1) {
            snprintf(err, ERR_LEN,
                     "--bootloader %s: data at 0x%04x-0x%04x lies outside the Uno's boot "
                     "section (0x%04x-0x%04x)",
                     path, chunks[i].baseaddr, chunks[i].baseaddr + chunks[i].size - 1,
                     UNO_BOOT_START, avr->flashend);
            free_ihex_chunks(chunks);
            return -1;
        }
        memcpy(avr->flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
    }
    free_ihex_chunks(chunks);
    avr->fuse[0] = UNO_LFUSE;
    avr->fuse[1] = UNO_HFUSE;
    avr->fuse[2] = UNO_EFUSE;
    avr->reset_pc = UNO_BOOT_START;
    avr->codeend = avr->flashend; /* the application avrdude writes runs too */
    avr->pc = UNO_BOOT_START;
    return 0;
}

struct sim {
    struct options opt;
    avr_t *avr;
    struct stage stage;
    struct bridge bridge;
    struct statesrv srv;
    struct eefile ee;
    int have_ee;
};

static size_t handle_request(void *ctx, const char *req, char *out, size_t len)
{
    struct sim *sim = ctx;

    if (!strcmp(req, "state")) return stage_format_state(&sim->stage, out, len);
    if (!strcmp(req, "stats")) return stage_format_stats(&sim->stage, out, len);
    if (!strcmp(req, "clear-stats")) {
        stage_clear_stats(&sim->stage);
        return (size_t)snprintf(out, len, "{\"ok\": true}\n");
    }
    if (!strcmp(req, "reset")) {
        /* the reset button (or DTR auto-reset): the MCU restarts, the
		 * motors stay where they are */
        external_reset(sim->avr, &sim->stage);
        return (size_t)snprintf(out, len, "{\"ok\": true}\n");
    }
    if (!strcmp(req, "uart")) {
        return (size_t)snprintf(
            out, len,
            "{\"rx_bytes\": %llu, \"tx_bytes\": %llu, \"tx_dropped\": %llu, \"rx_queued\": %zu, "
            "\"xon\": %llu, \"cycles_per_byte\": %llu, \"opens\": %llu, \"auto_resets\": %llu}\n",
            (unsigned long long)sim->bridge.rx_bytes, (unsigned long long)sim->bridge.tx_bytes,
            (unsigned long long)sim->bridge.tx_dropped, sim->bridge.rx_len,
            (unsigned long long)sim->bridge.xon,
            (unsigned long long)((avr_uart_t *)sim->bridge.uart)->cycles_per_byte,
            (unsigned long long)sim->bridge.opens, (unsigned long long)sim->bridge.auto_resets);
    }
    return (size_t)snprintf(
        out, len,
        "{\"error\": \"unknown request; valid: state, stats, clear-stats, reset, uart\"}\n");
}

static int sim_setup(struct sim *sim, FILE *out, char *err)
{
    static elf_firmware_t fw; /* large; static keeps it off the stack */
    struct options *o = &sim->opt;

    memset(&fw, 0, sizeof(fw));
    if (o->elf && elf_read_firmware(o->elf, &fw) != 0) {
        snprintf(err, ERR_LEN, "elf_read_firmware(%s): cannot load", o->elf);
        return -1;
    }
    if (!fw.mmcu[0]) snprintf(fw.mmcu, sizeof(fw.mmcu), "%s", o->mcu);
    if (!fw.frequency) fw.frequency = o->freq;
    if (strcmp(fw.mmcu, "atmega328p") && strcmp(fw.mmcu, "atmega328")) {
        snprintf(err, ERR_LEN, "%s: built for %s, the stage model is an atmega328p",
                 o->elf ? o->elf : "--mcu", fw.mmcu);
        return -1;
    }
    sim->avr = avr_make_mcu_by_name(fw.mmcu);
    if (!sim->avr) {
        snprintf(err, ERR_LEN, "avr_make_mcu_by_name(%s): unknown MCU", fw.mmcu);
        return -1;
    }
    if (avr_init(sim->avr) != 0) {
        snprintf(err, ERR_LEN, "avr_init(%s): failed", fw.mmcu);
        return -1;
    }
    sim->avr->log = (uint8_t)verbose_level;
    core_reset = sim->avr->reset;
    sim->avr->reset = reset_hook;
    set_sp_ramend(sim->avr);
    sim->avr->data[REG_MCUSR] = MCUSR_PORF; /* power-on */
    if (o->elf)
        avr_load_firmware(sim->avr, &fw);
    else
        sim->avr->frequency = fw.frequency;
    if (o->bootloader && load_bootloader(sim->avr, o->bootloader, err) < 0) return -1;
    sim->avr->sleep = sleep_none;

    for (int i = 0; i < STAGE_AXES; i++) {
        struct stage_axis *a = &sim->stage.axis[i];
        a->steps_per_deg = o->steps_per_deg[i];
        a->steps = lround(o->start[i] * o->steps_per_deg[i]);
        a->limit_enabled = o->limit_on[i];
        a->limit_deg = o->limit[i];
        a->limit_dir = o->limit_dir[i];
    }
    sim->stage.dir_invert_mask = o->dir_invert;
    sim->stage.step_invert_mask = o->step_invert;
    sim->stage.limit_width = o->limit_width;
    sim->stage.limit_hyst = o->limit_hyst;
    sim->stage.bounce_count = o->limit_bounce;
    sim->stage.bounce_cycles = (uint32_t)(o->limit_bounce_us * 1e-6 * fw.frequency);
    if (stage_attach(&sim->stage, sim->avr, err) < 0) return -1;
    if (o->eeprom) {
        if (ee_load(&sim->ee, sim->avr, o->eeprom, err) < 0) return -1;
        sim->have_ee = 1;
    }
    if (bridge_open(&sim->bridge, sim->avr, o->link, err) < 0) return -1;
    if (o->auto_reset && bridge_watch_opens(&sim->bridge, err) < 0) {
        bridge_close(&sim->bridge);
        return -1;
    }
    if (o->socket && srv_open(&sim->srv, o->socket, handle_request, sim, err) < 0) {
        bridge_close(&sim->bridge);
        return -1;
    }
    if (!o->socket) sim->srv.fd = -1;
    fprintf(out, "PTY %s\n", sim->bridge.path);
    if (o->socket) fprintf(out, "STATE %s\n", o->socket);
    fflush(out);
    return 0;
}

/* Returns 0 on a requested stop, -1 on an error or a stopped firmware. */
static int sim_run(struct sim *sim, char *err)
{
    avr_t *avr = sim->avr;
    double t0 = now_s(), last_save = t0;
    avr_cycle_count_t c0 = avr->cycle;
    struct pollfd fds[3 + SRV_CLIENTS];

    while (!stop_requested) {
        for (int i = 0; i < SLICE; i++) {
            int st = avr_run(avr);
            stage_note_sreg(&sim->stage);
            if (st == cpu_Done || st == cpu_Crashed) {
                snprintf(err, ERR_LEN, "firmware %s at pc 0x%04x, cycle %llu",
                         st == cpu_Done ? "stopped (sleep with interrupts off)" : "crashed",
                         avr->pc, (unsigned long long)avr->cycle);
                return -1;
            }
        }
        bridge_sync_baud(&sim->bridge);
        bridge_feed(&sim->bridge);
        stage_check_timer_traps(&sim->stage);

        /* pacing: sleep in poll(2) while simulated time is ahead of wall time */
        int timeout = 0;
        double wall = now_s();
        if (sim->opt.realtime) {
            double ahead = (double)(avr->cycle - c0) / avr->frequency - (wall - t0);
            if (ahead > 0.002) timeout = (int)(ahead * 1000.0);
            if (timeout > 20) timeout = 20;
            if (ahead < -MAX_LAG) { /* the host is slower than the chip: do not bank lag */
                t0 = wall;
                c0 = avr->cycle;
            }
        }
        int n = 0;
        fds[n].fd = sim->bridge.master;
        fds[n].events = (short)((bridge_want_read(&sim->bridge) ? POLLIN : 0) |
                                (bridge_want_write(&sim->bridge) ? POLLOUT : 0));
        n++;
        if (sim->bridge.ino >= 0) {
            fds[n].fd = sim->bridge.ino;
            fds[n].events = POLLIN;
            n++;
        }
        n += srv_pollfds(&sim->srv, fds + n);
        int r = poll(fds, (nfds_t)n, timeout);
        if (r < 0 && errno != EINTR) {
            snprintf(err, ERR_LEN, "poll: %s", strerror(errno));
            return -1;
        }
        /* a client opened the port: DTR resets the chip (before its
		 * bytes are read, so they reach the new session) */
        if (sim->bridge.ino >= 0 && r > 0 && fds[1].revents && bridge_check_opens(&sim->bridge)) {
            external_reset(avr, &sim->stage);
            bridge_flush(&sim->bridge);
        }
        /* only touch descriptors poll(2) flagged: a syscall per slice is
		 * cheap, four would cost a few percent of simulation speed */
        if ((r > 0 && fds[0].revents) || bridge_want_write(&sim->bridge))
            if (bridge_poll_io(&sim->bridge, err) < 0) return -1;
        int srv_ready = 0;
        for (int i = sim->bridge.ino >= 0 ? 2 : 1; i < n && r > 0; i++)
            srv_ready |= fds[i].revents != 0;
        if (srv_ready) srv_service(&sim->srv);
        bridge_feed(&sim->bridge);
        stage_sync_limits(&sim->stage);

        if (sim->have_ee && wall - last_save > EE_SAVE_EVERY) {
            last_save = wall;
            if (ee_save(&sim->ee, err) < 0)
                fprintf(stderr, "stagesim: %s\n", err); /* keep running; retried */
        }
    }
    return 0;
}

int main(int argc, char **argv)
{
    static struct sim sim;
    char err[ERR_LEN] = "";
    struct sigaction sa;
    FILE *out;
    int out_fd, rc = 1;

    if (parse_options(argc, argv, &sim.opt, err) < 0) {
        fprintf(stderr, "stagesim: %s\n", err);
        return 2;
    }
    verbose_level = LOG_ERROR + sim.opt.verbose;
    avr_global_logger_set(logger);

    /* Our stdout is a protocol (PTY/STATE lines): keep it for us, and send
	 * anything a library prints on fd 1 to stderr instead. */
    out_fd = dup(STDOUT_FILENO);
    if (out_fd < 0 || dup2(STDERR_FILENO, STDOUT_FILENO) < 0 || !(out = fdopen(out_fd, "w"))) {
        fprintf(stderr, "stagesim: dup(stdout): %s\n", strerror(errno));
        return 1;
    }

    memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);
    signal(SIGHUP, SIG_IGN);

    sim.srv.fd = -1;
    if (sim_setup(&sim, out, err) < 0) {
        fprintf(stderr, "stagesim: %s\n", err);
        if (sim.avr) avr_terminate(sim.avr);
        return 1;
    }
    if (sim_run(&sim, err) < 0)
        fprintf(stderr, "stagesim: %s\n", err);
    else
        rc = 0;

    if (sim.have_ee && ee_save(&sim.ee, err) < 0) {
        fprintf(stderr, "stagesim: %s\n", err);
        rc = 1;
    }
    srv_close(&sim.srv);
    bridge_close(&sim.bridge);
    avr_terminate(sim.avr);
    fclose(out);
    return rc;
}
