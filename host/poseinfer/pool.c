/* pool.c -- worker threads for the daemon. Each worker has its own clone of
 * the model (pi_clone: the ONNX Runtime session is shared, Run is
 * thread-safe; the buffers and preprocessing are per thread), re-made after
 * a reload. After a large frame a worker gives its buffers and the heap's
 * free memory back to the system. */
#define _GNU_SOURCE
#include "pool.h"

#include <errno.h>
#include <malloc.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>

#include "internal.h"

/* A frame over this many bytes (file or pixels) is not kept after its job. */
#define KEEP_BYTES (8u * 1024 * 1024)

typedef struct worker {
    pool *p;
    pthread_t th;
    pi_ctx *ctx;
    unsigned long gen;
} worker;

struct pool {
    app *a;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    job *head, *tail;   /* queued */
    job *dhead, *dtail; /* done */
    int queued, stop, n, efd;
    worker *w;
};

void job_free(job *j)
{
    if (!j) return;
    free(j->arg);
    free(j->img);
    sb_free(&j->out);
    free(j);
}

/* The worker's clone of the current model (re-made after a reload). */
static pi_ctx *worker_ctx(worker *w)
{
    app *a = w->p->a;
    pi_ctx *old = NULL;
    char err[PI_ERR_LEN];
    pthread_mutex_lock(&a->lock);
    if (!w->ctx || w->gen != a->gen) {
        old = w->ctx;
        w->ctx = a->ctx ? pi_clone(a->ctx, err) : NULL;
        w->gen = a->gen;
        if (a->ctx && !w->ctx) log_msg("worker: %s", err);
    }
    pthread_mutex_unlock(&a->lock);
    pi_close(old);
    return w->ctx;
}

static void *worker_main(void *arg)
{
    worker *w = arg;
    pool *p = w->p;
    for (;;) {
        job *j;
        pthread_mutex_lock(&p->mu);
        while (!p->head && !p->stop) pthread_cond_wait(&p->cv, &p->mu);
        if (p->stop) {
            pthread_mutex_unlock(&p->mu);
            break;
        }
        j = p->head;
        p->head = j->next;
        if (!p->head) p->tail = NULL;
        p->queued--;
        pthread_mutex_unlock(&p->mu);

        j->next = NULL;
        proto_run(p->a, j->kind == JOB_RELOAD ? NULL : worker_ctx(w), j);
        /* A large frame: give its memory back (the image of a JOB_FRAME is
         * freed here too, not when the event loop gets round to it). */
        {
            int big = j->len > KEEP_BYTES;
            free(j->img);
            j->img = NULL;
            if (pi_release_large(w->ctx, KEEP_BYTES) || big) malloc_trim(0);
        }
        pthread_mutex_lock(&p->mu);
        if (p->dtail)
            p->dtail->next = j;
        else
            p->dhead = j;
        p->dtail = j;
        pthread_mutex_unlock(&p->mu);
        {
            uint64_t one = 1;
            ssize_t r = write(p->efd, &one, sizeof one); /* wake the event loop */
            (void)r;
        }
    }
    pi_close(w->ctx);
    w->ctx = NULL;
    return NULL;
}

pool *pool_start(app *a, int n, char *err)
{
    pool *p = calloc(1, sizeof *p);
    if (!p) {
        pi_seterr(err, "pool: out of memory");
        return NULL;
    }
    p->a = a;
    p->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    p->w = calloc((size_t)n, sizeof *p->w);
    if (p->efd < 0 || !p->w) {
        pi_seterr(err, "pool: %s", p->efd < 0 ? strerror(errno) : "out of memory");
        if (p->efd >= 0) close(p->efd);
        free(p->w);
        free(p);
        return NULL;
    }
    pthread_mutex_init(&p->mu, NULL);
    pthread_cond_init(&p->cv, NULL);
    for (int i = 0; i < n; i++) {
        int rc;
        p->w[i].p = p;
        rc = pthread_create(&p->w[i].th, NULL, worker_main, &p->w[i]);
        if (rc != 0) {
            pi_seterr(err, "pool: pthread_create: %s", strerror(rc));
            pool_stop(p);
            return NULL;
        }
        p->n++;
    }
    return p;
}

void pool_submit(pool *p, job *j)
{
    j->next = NULL;
    pthread_mutex_lock(&p->mu);
    if (p->tail)
        p->tail->next = j;
    else
        p->head = j;
    p->tail = j;
    p->queued++;
    pthread_cond_signal(&p->cv);
    pthread_mutex_unlock(&p->mu);
}

job *pool_done(pool *p)
{
    job *j;
    uint64_t v;
    ssize_t r = read(p->efd, &v, sizeof v);
    (void)r;
    pthread_mutex_lock(&p->mu);
    j = p->dhead;
    p->dhead = p->dtail = NULL;
    pthread_mutex_unlock(&p->mu);
    return j;
}

int pool_fd(const pool *p)
{
    return p->efd;
}

int pool_queued(pool *p)
{
    int n;
    pthread_mutex_lock(&p->mu);
    n = p->queued;
    pthread_mutex_unlock(&p->mu);
    return n;
}

void pool_stop(pool *p)
{
    if (!p) return;
    pthread_mutex_lock(&p->mu);
    p->stop = 1;
    pthread_cond_broadcast(&p->cv);
    pthread_mutex_unlock(&p->mu);
    for (int i = 0; i < p->n; i++) pthread_join(p->w[i].th, NULL);
    for (job *j = p->head, *nx; j; j = nx) {
        nx = j->next;
        job_free(j);
    }
    for (job *j = p->dhead, *nx; j; j = nx) {
        nx = j->next;
        job_free(j);
    }
    pthread_mutex_destroy(&p->mu);
    pthread_cond_destroy(&p->cv);
    close(p->efd);
    free(p->w);
    free(p);
}
