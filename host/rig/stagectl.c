/* stagectl -- drive the rotation stage from a shell, one command per run.
 * A thin front end of the stage client (stage.h): what works here works in
 * poserig, so it is also how the tests reach the client from outside. */
#define _DEFAULT_SOURCE
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "stage.h"

static void usage(FILE *f)
{
    fputs("usage: stagectl [options] COMMAND [ARGS]\n"
          "\n"
          "Commands:\n"
          "  list              serial ports libserialport sees (known Arduinos marked)\n"
          "  pos | status      one status report: state, MPos and WPos (degrees)\n"
          "  home              homing cycle ($H), then wait until Idle\n"
          "  move X Y Z        absolute move in degrees (G90 G0, or G1 with --feed), wait until "
          "Idle\n"
          "  settings          all settings ($$), one $N=value per line\n"
          "  set N V           set one setting ($N=V)\n"
          "  unlock            clear an alarm ($X)\n"
          "  hold              feed hold ('!')\n"
          "  reset             soft reset (0x18), wait for the banner, print the state\n"
          "  recover           reset, then re-home (--rehome) or unlock as the alarm allows\n"
          "  send LINE         send one line, print what came back before its ok\n"
          "\n"
          "Options:\n"
          "  --port PATH|auto  serial port or pty of the stage (default auto: first Arduino by USB "
          "VID:PID)\n"
          "  --feed DEG_MIN    feed for move (default: rapid, G0)\n"
          "  --rehome          recover: home when the alarm lost the position\n"
          "  --reset-on-open   soft-reset right after opening the port\n"
          "  --banner-timeout MS  wait for the banner (default 5000)\n"
          "  --timeout MS      wait for each reply (default 2000)\n"
          "  --poll MS         status poll period while moving (default 100)\n"
          "  --move-timeout MS deadline of one move or homing (default 120000)\n"
          "  -v, --verbose     trace the serial traffic on stderr\n"
          "  -h, --help        this text\n"
          "\n"
          "A controller that restored its default settings (EEPROM failed its CRC check) is\n"
          "reported on stderr after the command.\n"
          "\n"
          "Exit status: 0 done, 1 the stage failed or refused, 2 usage error.\n",
          f);
}

static int parse_num(const char *s, double *v)
{
    char *end;
    errno = 0;
    *v = strtod(s, &end);
    return (end == s || *end || errno) ? -1 : 0;
}

static int parse_ms(const char *s, int *v)
{
    double d;
    if (parse_num(s, &d) != 0 || d < 1 || d > 3600000) return -1;
    *v = (int)d;
    return 0;
}

static void print_status(const stage_status_report *st)
{
    printf("%s", st->state);
    if (st->substate >= 0) printf(":%d", st->substate);
    printf(" MPos %.3f %.3f %.3f WPos %.3f %.3f %.3f\n", st->mpos[0], st->mpos[1], st->mpos[2],
           st->wpos[0], st->wpos[1], st->wpos[2]);
}

static void print_line(void *ctx, const char *line)
{
    (void)ctx;
    printf("%s\n", line);
}

int main(int argc, char **argv)
{
    static const struct option longopts[] = {
        {"port", required_argument, 0, 'p'},
        {"feed", required_argument, 0, 'f'},
        {"rehome", no_argument, 0, 'R'},
        {"reset-on-open", no_argument, 0, 'r'},
        {"banner-timeout", required_argument, 0, 'b'},
        {"timeout", required_argument, 0, 't'},
        {"poll", required_argument, 0, 'P'},
        {"move-timeout", required_argument, 0, 'm'},
        {"verbose", no_argument, 0, 'v'},
        {"help", no_argument, 0, 'h'},
        {0, 0, 0, 0},
    };
    char err[RIG_ERR_LEN];
    const char *port = "auto", *cmd;
    double feed = 0, xyz[3] = {0, 0, 0}, setn = 0, setv = 0;
    int rehome = 0, c, rc = 1, nargs;
    stage_opts o;
    stage s;

    stage_opts_default(&o);
    /* '+': stop at the command, so "move -5 0 0" is not taken for options. */
    while ((c = getopt_long(argc, argv, "+vh", longopts, NULL)) != -1) {
        switch (c) {
        case 'p': port = optarg; break;
        case 'f':
            if (parse_num(optarg, &feed) != 0 || feed <= 0) goto badarg;
            break;
        case 'R': rehome = 1; break;
        case 'r': o.reset_on_open = 1; break;
        case 'b':
            if (parse_ms(optarg, &o.banner_timeout_ms) != 0) goto badarg;
            break;
        case 't':
            if (parse_ms(optarg, &o.reply_timeout_ms) != 0) goto badarg;
            break;
        case 'P':
            if (parse_ms(optarg, &o.poll_ms) != 0) goto badarg;
            break;
        case 'm':
            if (parse_ms(optarg, &o.move_timeout_ms) != 0) goto badarg;
            o.home_timeout_ms = o.move_timeout_ms;
            break;
        case 'v': o.log = stderr; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return 2;
        }
    }
    if (optind >= argc) {
        usage(stderr);
        return 2;
    }
    cmd = argv[optind];
    nargs = argc - optind - 1;

    if (strcmp(cmd, "list") == 0) {
        int n = stage_list_ports(stdout, err);
        if (n < 0) {
            fprintf(stderr, "stagectl: %s\n", err);
            return 1;
        }
        if (n == 0) fprintf(stderr, "stagectl: no serial ports found\n");
        return 0;
    }

    { /* Check the arguments before touching the stage. */
        static const struct {
            const char *name;
            int nargs;
        } cmds[] = {
            {"pos", 0},    {"status", 0}, {"home", 0},  {"move", 3},    {"settings", 0}, {"set", 2},
            {"unlock", 0}, {"hold", 0},   {"reset", 0}, {"recover", 0}, {"send", 1},
        };
        size_t i;
        for (i = 0; i < sizeof(cmds) / sizeof(cmds[0]); i++)
            if (strcmp(cmd, cmds[i].name) == 0) break;
        if (i == sizeof(cmds) / sizeof(cmds[0])) {
            fprintf(stderr,
                    "stagectl: unknown command '%s' (list, pos, status, home, move, settings, "
                    "set, unlock, hold, reset, recover, send)\n",
                    cmd);
            return 2;
        }
        if (nargs != cmds[i].nargs) {
            fprintf(stderr, "stagectl: %s takes %d argument(s), got %d\n", cmd, cmds[i].nargs,
                    nargs);
            return 2;
        }
    }

    if (strcmp(cmd, "move") == 0) {
        int i;
        for (i = 0; i < 3; i++) {
            if (parse_num(argv[optind + 1 + i], &xyz[i]) != 0) {
                fprintf(stderr, "stagectl: move: '%s' is not a number of degrees\n",
                        argv[optind + 1 + i]);
                return 2;
            }
        }
    } else if (strcmp(cmd, "set") == 0) {
        if (parse_num(argv[optind + 1], &setn) != 0 || setn < 0 || setn > 9999 ||
            setn != (int)setn || parse_num(argv[optind + 2], &setv) != 0) {
            fprintf(stderr, "stagectl: set: needs an integer setting number and a number\n");
            return 2;
        }
    }

    if (stage_open(&s, port, &o, err) != 0) {
        fprintf(stderr, "stagectl: %s\n", err);
        return 1;
    }
    if (strcmp(cmd, "pos") == 0 || strcmp(cmd, "status") == 0) {
        stage_status_report st;
        if (stage_status(&s, &st, err) != 0) goto fail;
        print_status(&st);
    } else if (strcmp(cmd, "home") == 0) {
        if (stage_home(&s, err) != 0) goto fail;
        print_status(&s.last);
    } else if (strcmp(cmd, "move") == 0) {
        if (stage_move_wait(&s, xyz, feed, err) != 0) goto fail;
        print_status(&s.last);
    } else if (strcmp(cmd, "settings") == 0) {
        stage_setting set[STAGE_MAX_SETTINGS];
        int n, i;
        if (stage_get_settings(&s, set, STAGE_MAX_SETTINGS, &n, err) != 0) goto fail;
        for (i = 0; i < n; i++) printf("$%d=%.3f\n", set[i].n, set[i].value);
    } else if (strcmp(cmd, "set") == 0) {
        if (stage_set_setting(&s, (int)setn, setv, err) != 0) goto fail;
    } else if (strcmp(cmd, "unlock") == 0) {
        if (stage_unlock(&s, err) != 0) goto fail;
    } else if (strcmp(cmd, "hold") == 0) {
        if (stage_feed_hold(&s, err) != 0) goto fail;
    } else if (strcmp(cmd, "reset") == 0) {
        if (stage_reset(&s, err) != 0) goto fail;
        print_status(&s.last);
    } else if (strcmp(cmd, "recover") == 0) {
        if (stage_recover(&s, rehome, err) != 0) goto fail;
        print_status(&s.last);
    } else if (strcmp(cmd, "send") == 0) {
        if (stage_command(&s, argv[optind + 1], 0, print_line, NULL, err) != 0) goto fail;
    }
    rc = 0;
    goto out;
fail:
    fprintf(stderr, "stagectl: %s\n", err);
    rc = 1;
out:
    if (s.defaults_restored) /* the firmware says it once, at boot: this may be the only chance */
        fprintf(stderr,
                "stagectl: warning: the controller says '%s': it runs on the firmware's default "
                "settings (steps per degree, limits, rates), not the rig's; compare 'stagectl "
                "settings' "
                "with the rig's values and set them again\n",
                s.restored_msg);
    stage_close(&s);
    return rc;
badarg:
    fprintf(stderr, "stagectl: bad value '%s' for an option\n", optarg);
    return 2;
}
