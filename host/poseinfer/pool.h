/* pool.h -- the daemon's worker threads: jobs in, finished jobs out, a
 * descriptor that the event loop polls to learn that some have finished. */
#ifndef PI_POOL_H
#define PI_POOL_H

#include "server.h"

typedef struct pool pool;

/* Start n workers for app a. NULL + err on failure. */
pool *pool_start(app *a, int n, char *err);

/* Queue a job (the pool owns it until pool_done hands it back). */
void pool_submit(pool *p, job *j);

/* The jobs finished since the last call, oldest first, or NULL. */
job *pool_done(pool *p);

/* Readable when jobs have finished (drained by pool_done). */
int pool_fd(const pool *p);

/* Jobs queued and not yet started. */
int pool_queued(pool *p);

/* Let the workers finish the jobs they are on, join them, free the rest. */
void pool_stop(pool *p);

#endif
