/* jobs.h — every render the HTTP service runs is a job: one worker thread renders them one
 * at a time, in order, behind a bounded queue (the render context allows one render at a
 * time, and lavapipe already spreads one render over every core, so running renders side by
 * side would only make each slower; a bounded queue turns overload into an immediate 503).
 *
 * A synchronous request submits a job and waits for it (job_wait); an asynchronous one
 * (Prefer: respond-async) and every sweep are kept in the store under an unguessable id,
 * with their state, progress, an event log for Server-Sent Events, and their result, until
 * they expire (ttl after they finish) or the store's byte budget needs their room.
 *
 * Locking: one mutex guards the whole store (queue, jobs, events); it is held only for
 * bookkeeping, never while rendering or encoding. A job is reference counted: the store's
 * table, the queue and each connection using it hold a reference (job_find / job_release),
 * so an expired job stays valid for whoever is still sending it.
 */
#ifndef NS_JOBS_H
#define NS_JOBS_H

#include <stdint.h>

#include <jansson.h>

#include "encode.h"
#include "nscatter.h"
#include "scene_json.h"

#define JOB_ID_CHARS 32 /* 128 random bits as lower-case hex */
/* An instance's name (serve --instance) goes before them, "name-<32 hex>", so that a load
 * balancer can send a job's requests to the instance that holds it (deploy/nginx.conf). */
#define JOB_INSTANCE_MAX 16
#define JOB_ID_MAX (JOB_INSTANCE_MAX + 1 + JOB_ID_CHARS)
#define JOB_DEFAULT_TTL_S 3600u
#define JOB_DEFAULT_STORE_BYTES (1ull << 30)
#define JOB_MAX_STORED 4096u    /* finished jobs kept at most, whatever their size */
#define JOB_MAX_EVENTS 20000u   /* per job; progress ticks are dropped past it, never the rest */
#define JOB_TICK_INTERVAL_MS 100.0

typedef enum { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_FAILED, JOB_CANCELLED, JOB_STATE_COUNT } job_state;
typedef enum { JOB_RENDER, JOB_SWEEP } job_kind;

const char *job_state_name(job_state state);

typedef struct job job;
typedef struct job_store job_store;
struct sweep;

typedef struct job_store_desc {
    ns_context *ctx;
    uint32_t capacity;     /* jobs admitted at once (queued and running); 0: 1 */
    uint32_t ttl_s;        /* finished jobs are kept this long; 0: JOB_DEFAULT_TTL_S */
    uint64_t max_bytes;    /* results kept at most; 0: JOB_DEFAULT_STORE_BYTES */
    const char *asset_dir; /* for the scenes of sweep variants, parsed when they render */
    /* Longest render.deadline_ms a render gets, and the deadline of one that names none
     * (0: no cap, and no deadline unless the scene names one). */
    uint32_t max_deadline_ms;
    /* 1..JOB_INSTANCE_MAX of [a-z0-9], the prefix of every id; NULL: ids without one. */
    const char *instance;
    /* 1: no work between jobs. Otherwise, once the queue has been empty for
     * JOB_IDLE_AFTER_MS after a job, the worker calls ns_context_idle_work until it finds
     * nothing to do, and a job that arrives stops the call at its next device submission;
     * after a stopped call the quiet asked for doubles, up to JOB_IDLE_AFTER_MAX_MS. */
    int no_idle_work;
} job_store_desc;

#define JOB_IDLE_AFTER_MS 1000.0
#define JOB_IDLE_AFTER_MAX_MS 16000.0

/* The quiet the worker waits for before its next call of idle work, after a call that was
 * stopped by a job (stopped 1) or that ended (0) with `quiet_ms` asked for before it. A
 * client that sends its renders a little less often than a call lasts would stop every
 * call, wait for each, and never get the nodes: after each stopped call the quiet doubles,
 * up to JOB_IDLE_AFTER_MAX_MS; a call that ends resets it to JOB_IDLE_AFTER_MS. */
double job_idle_quiet_next_ms(double quiet_ms, int stopped);

int job_store_create(const job_store_desc *desc, job_store **out, ns_error *err);
/* When the service begins to stop: admits nothing new, cancels every asynchronous job
 * (queued ones at once, running ones at their next dispatch) and ends every event stream.
 * Synchronous jobs already admitted still finish, and their connections still wait. */
void job_store_shutdown(job_store *store);
/* Joins the worker and frees everything; every connection must be gone. NULL allowed. */
void job_store_destroy(job_store *store);

/* Admits a render of `doc` (taken over on success; the caller keeps it on failure).
 * `stats` holds the stages so far (parse). async: kept in the store under an id; else the
 * caller waits with job_wait, and the worker encodes the image as sync_format. On success
 * *out holds a reference for the caller. Returns NS_ERR_LIMIT with *retry_after_s when the
 * queue is full. */
int job_submit_render(job_store *store, scene_doc *doc, int async, encode_format sync_format,
                      const ns_render_stats *stats, job **out, uint32_t *retry_after_s);
/* Admits a sweep (taken over on success), always asynchronous. */
int job_submit_sweep(job_store *store, struct sweep *sweep, const ns_render_stats *stats,
                     job **out, uint32_t *retry_after_s);

/* 1 when a job submitted now would be refused (the queue full, or the service stopping),
 * with *retry_after_s an estimate of when a slot frees up (whole seconds, >= 1): lets the
 * service answer 503 before reading a request's body. */
int job_store_full(job_store *store, uint32_t *retry_after_s);

/* The job with this id and kind, with a reference for the caller, or NULL: *gone is 1 when
 * the id was a job's that has expired or was discarded (410), 0 when it never was (404). */
job *job_find(job_store *store, const char *id, job_kind kind, int *gone);
void job_release(job_store *store, job *job);

/* Waits until the job has finished. At least every 100 ms (and whenever a job changes)
 * `client_gone` (may be NULL) is asked whether the client is still there; when it says 1,
 * the job is cancelled and still waited for (the device is free again when this returns). */
void job_wait(job_store *store, job *job, int (*client_gone)(void *user), void *user);

typedef enum {
    JOB_CANCELLED_QUEUED,   /* it left the queue, state cancelled */
    JOB_CANCEL_REQUESTED,   /* running: it stops at its next dispatch */
    JOB_DISCARDED,          /* it had finished: removed, its id answers 410 from now on */
} job_cancel_result;
job_cancel_result job_cancel(job_store *store, job *job);

/* The job's description (docs/http.md "Job JSON"). New reference. */
json_t *job_json(job_store *store, job *job);
/* Sweeps' manifest.json. */
json_t *job_manifest_json(job_store *store, job *job);

/* A finished job's result, for a synchronous answer: status, error and the encoded image
 * (moved out: the caller frees it), with the stats (timings). */
int job_take_sync_result(job_store *store, job *job, encode_buffer *image, ns_render_stats *stats,
                         ns_error *err);

/* Encodes the image of a done render (variant -1) or of a sweep's variant n. Returns 0;
 * NS_ERR_NOT_AVAILABLE when it is not done (*state says what it is); NS_ERR_INVALID_ARGUMENT
 * for a variant out of range. stats receives its timings (for Server-Timing). */
int job_encode_image(job_store *store, job *job, int variant, encode_format format,
                     encode_buffer *out, ns_render_stats *stats, job_state *state, ns_error *err);
/* The sweep's contact sheet as PNG, as far as it has rendered. */
int job_sweep_sheet(job_store *store, job *job, encode_buffer *out, ns_error *err);

/* Server-Sent Events: the events after `after`, formatted (id/event/data lines), waiting
 * up to timeout_ms for one when there is none yet. *text is malloc'ed ("" when none came:
 * the caller sends a keep-alive comment); *last is the id of the last event in it; *ended
 * is 1 once the final event is in the text or was sent before (the stream should close). */
int job_events_wait(job_store *store, job *job, uint64_t after, double timeout_ms, char **text,
                    uint64_t *last, int *ended);

/* Counts for /v1/info: admitted now (queued + running), jobs by state, bytes kept. */
typedef struct job_store_counts {
    uint32_t admitted;
    uint32_t by_state[JOB_STATE_COUNT];
    uint64_t bytes;
    /* Work between jobs: still to look for (0/1: the worker will call at its next quiet
     * moment, or is calling), running now (0/1), nodes made, calls a job stopped, seconds
     * spent. */
    int idle_pending, idle_running;
    uint64_t idle_nodes, idle_stopped;
    double idle_seconds;
} job_store_counts;
void job_store_count(job_store *store, job_store_counts *out);

/* Jobs in the store of one kind, newest first, as job_json. New reference. */
json_t *job_list_json(job_store *store, job_kind kind);

#endif
