/* render_queue.h — the HTTP service's renders, one at a time on one worker thread, behind
 * a bounded queue. The render context allows one render at a time, and lavapipe already
 * uses every core for one render, so running renders side by side would only make each
 * slower; a bounded queue turns overload into an immediate 503 instead of a pile-up.
 *
 * A connection thread fills a render_request, submits it, and blocks in
 * render_queue_wait() until the worker has rendered and encoded it. The request (and the
 * scene it points to) belongs to the connection thread throughout; the worker only reads
 * the inputs and writes the outputs.
 */
#ifndef NS_RENDER_QUEUE_H
#define NS_RENDER_QUEUE_H

#include <stdint.h>

#include "encode.h"
#include "nscatter.h"

typedef struct render_request {
    /* inputs */
    const ns_scene *scene;
    encode_format format;
    float exposure_stops;
    /* outputs, valid after render_queue_wait(): status 0 and image, or status and err.
     * stats gets a "queue" stage (time spent waiting) before the render's own stages. */
    int status;
    ns_error err;
    encode_buffer image;
    ns_render_stats stats;
    /* internal */
    double submitted_ms;
    int done;
    struct render_request *next;
} render_request;

typedef struct render_queue render_queue;

/* capacity: renders admitted at once, the running one included (>= 1). */
int render_queue_create(ns_context *ctx, uint32_t capacity, render_queue **out, ns_error *err);

/* Admits the request, or returns NS_ERR_LIMIT when `capacity` renders are already admitted;
 * then *retry_after_s is an estimate of when a slot frees up (whole seconds, >= 1). */
int render_queue_submit(render_queue *q, render_request *req, uint32_t *retry_after_s);

/* Blocks until the worker has finished req. */
void render_queue_wait(render_queue *q, render_request *req);

/* Renders admitted now (waiting and running). */
uint32_t render_queue_length(render_queue *q);

/* Finishes every admitted request, stops the worker and frees the queue. NULL allowed. */
void render_queue_destroy(render_queue *q);

#endif
