/* render_queue.c — one render worker thread behind a bounded FIFO. */
#include "render_queue.h"

#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "render_job.h"

struct render_queue {
    ns_context *ctx;
    uint32_t capacity;
    uint32_t admitted; /* waiting + running */
    render_request *head, *tail;
    int stopping;
    double average_ms; /* moving average of a render's duration, for Retry-After */
    pthread_mutex_t lock;
    pthread_cond_t work;     /* signalled when a request arrives or on stop */
    pthread_cond_t finished; /* broadcast when a request is done */
    pthread_t worker;
};

static void run_one(render_queue *q, render_request *req)
{
    double start = ns_now_ms();
    ns_stats_add_stage(&req->stats, "queue", start - req->submitted_ms);
    req->status = render_job_run(q->ctx, req->scene, req->format, req->exposure_stops, &req->stats,
                                 &req->image, &req->err);
    double took = ns_now_ms() - start;
    pthread_mutex_lock(&q->lock);
    q->average_ms = q->average_ms > 0 ? 0.7 * q->average_ms + 0.3 * took : took;
    req->done = 1;
    q->admitted--;
    pthread_cond_broadcast(&q->finished);
    pthread_mutex_unlock(&q->lock);
}

static void *render_worker(void *arg)
{
    render_queue *q = arg;
    for (;;) {
        pthread_mutex_lock(&q->lock);
        while (!q->head && !q->stopping)
            pthread_cond_wait(&q->work, &q->lock);
        render_request *req = q->head;
        if (!req) { /* stopping and nothing left */
            pthread_mutex_unlock(&q->lock);
            return NULL;
        }
        q->head = req->next;
        if (!q->head)
            q->tail = NULL;
        pthread_mutex_unlock(&q->lock);
        run_one(q, req);
    }
}

int render_queue_create(ns_context *ctx, uint32_t capacity, render_queue **out, ns_error *err)
{
    *out = NULL;
    render_queue *q = calloc(1, sizeof *q);
    if (!q) {
        err->status = NS_ERR_OUT_OF_HOST_MEMORY;
        snprintf(err->message, sizeof err->message, "render queue: out of memory");
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    q->ctx = ctx;
    q->capacity = capacity ? capacity : 1;
    pthread_mutex_init(&q->lock, NULL);
    pthread_cond_init(&q->work, NULL);
    pthread_cond_init(&q->finished, NULL);
    if (pthread_create(&q->worker, NULL, render_worker, q) != 0) {
        pthread_cond_destroy(&q->finished);
        pthread_cond_destroy(&q->work);
        pthread_mutex_destroy(&q->lock);
        free(q);
        err->status = NS_ERR_INTERNAL;
        snprintf(err->message, sizeof err->message, "render queue: cannot start the worker");
        return NS_ERR_INTERNAL;
    }
    *out = q;
    return 0;
}

int render_queue_submit(render_queue *q, render_request *req, uint32_t *retry_after_s)
{
    pthread_mutex_lock(&q->lock);
    if (q->admitted >= q->capacity || q->stopping) {
        /* Everything admitted must finish before a new slot opens; assume the one running
         * is half done. */
        double wait_s = q->average_ms * ((double)q->admitted - 0.5) / 1000.0;
        pthread_mutex_unlock(&q->lock);
        double rounded = ceil(wait_s);
        *retry_after_s = rounded < 1.0 ? 1u : rounded > 3600.0 ? 3600u : (uint32_t)rounded;
        return NS_ERR_LIMIT;
    }
    req->done = 0;
    req->next = NULL;
    req->submitted_ms = ns_now_ms();
    if (q->tail)
        q->tail->next = req;
    else
        q->head = req;
    q->tail = req;
    q->admitted++;
    pthread_cond_signal(&q->work);
    pthread_mutex_unlock(&q->lock);
    return 0;
}

void render_queue_wait(render_queue *q, render_request *req)
{
    pthread_mutex_lock(&q->lock);
    while (!req->done)
        pthread_cond_wait(&q->finished, &q->lock);
    pthread_mutex_unlock(&q->lock);
}

uint32_t render_queue_length(render_queue *q)
{
    pthread_mutex_lock(&q->lock);
    uint32_t n = q->admitted;
    pthread_mutex_unlock(&q->lock);
    return n;
}

void render_queue_destroy(render_queue *q)
{
    if (!q)
        return;
    pthread_mutex_lock(&q->lock);
    q->stopping = 1;
    pthread_cond_signal(&q->work);
    pthread_mutex_unlock(&q->lock);
    pthread_join(q->worker, NULL);
    pthread_cond_destroy(&q->finished);
    pthread_cond_destroy(&q->work);
    pthread_mutex_destroy(&q->lock);
    free(q);
}
