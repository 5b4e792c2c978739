/* config.h -- poseinfer settings: a config file (key = value) and flags, the
 * flags overriding the file. */
#ifndef PI_CONFIG_H
#define PI_CONFIG_H

typedef struct pi_config {
    char *model;  /* model = FILE.onnx */
    char *serve;  /* serve = unix:PATH | tcp:127.0.0.1:PORT */
    char *camera; /* camera = /dev/video0 | 0 | gst:... | unix:PATH */
    char *
        camera_file; /* camera_file = FILE: camera file for a sphere-crop-v2 model (radius, lens) */
    char *dump_tensor; /* (flag only) write the input tensor of one image */
    int continuous;    /* continuous = yes|no: capture mode */
    long count;        /* count = N: frames in continuous mode (0 = until stopped) */
    char *save_frames; /* save_frames = DIR: continuous mode writes each frame there */
    int interval_ms;   /* interval_ms = N: pause between continuous frames */
    int threads;       /* threads = N: ONNX Runtime intra-op threads */
    int warmup;        /* warmup = N: warm-up runs at model load */
    long max_pixels;   /* max_pixels = N: refuse larger frames */
    int timeout_ms;    /* timeout_ms = N: frame-server timeout */
    int timings;       /* timings = yes|no: add decode/preprocess/infer ms */
    int refine;        /* refine = yes|no: refine against the model's texture (docs/refine.md) */
    /* The daemon as a shared service (docs/poseinfer.md, "Who may ask for what"). */
    int socket_mode;    /* socket_mode = 0660: permissions of the unix: socket */
    char *socket_group; /* socket_group = NAME|GID: group of the unix: socket */
    char **allow_dirs;  /* allow_dir = DIR (repeatable): where `infer PATH` may read */
    int n_allow_dirs;
    int tcp_remote;   /* tcp_remote = yes|no: a tcp: address other than loopback */
    char *token_file; /* token_file = FILE: TCP clients first send "auth TOKEN" */
    /* Bounds against a client that would hold the daemon. */
    int workers;         /* workers = N: threads that infer frames (default 2) */
    int max_clients;     /* max_clients = N: connections at once (default 64) */
    int idle_timeout_ms; /* idle_timeout_ms = N: close a client idle this long */
    long max_file_bytes; /* max_file_bytes = N: refuse larger image files and frames */
} pi_config;

/* Defaults. */
void config_init(pi_config *c);

/* Free the strings. */
void config_free(pi_config *c);

/* Set one key (file keys; '-' and '_' are the same). 0, or -1 with
 * err "reason". */
int config_set(pi_config *c, const char *key, const char *value, char *err);

/* The name of the i-th config file key (0, 1, ...), NULL past the last. */
const char *config_key(int i);

/* Forget the allow_dir list (a --allow-dir flag replaces the file's list). */
void config_clear_allow_dirs(pi_config *c);

/* Read a config file: "key = value" lines, '#' comments, blank lines.
 * Errors name the file and line: "config(FILE:LINE): reason". */
int config_load(pi_config *c, const char *path, char *err);

#endif
