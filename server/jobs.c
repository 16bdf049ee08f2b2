/* jobs.c — the job store, its queue and its render worker (jobs.h). */
#include "jobs.h"

#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>

#include "contact_sheet.h"
#include "metrics.h"
#include "problem.h"
#include "render_job.h"
#include "sweep.h"

#define TOMBSTONES 4096u /* ids of expired or discarded jobs remembered, to answer 410 */

typedef struct job_event {
    uint64_t id;
    char name[24];
    char *data; /* compact JSON */
} job_event;

/* What a render (or one sweep variant) leaves behind. `scene` keeps only the camera and the
 * render settings (the image's metadata); its pointers are NULL. */
typedef struct job_result {
    job_state state;
    ns_render_stats stats;
    ns_image image;
    ns_scene scene;
    json_t *error; /* problem+json when failed */
    ns_error err;  /* the status and message behind it */
    double started_ms, finished_ms;
} job_result;

struct job {
    char id[JOB_ID_MAX + 1];
    job_kind kind;
    int async;
    int refs;
    job_state state;
    int cancel; /* the render library reads it (ns_render_control.cancel) */
    int cancel_requested;
    double progress;
    char stage[32];
    double created_wall, started_wall, finished_wall; /* seconds since the epoch */
    double submitted_ms;
    ns_render_stats parse_stats; /* stages before the queue (parse) */
    ns_render_stats live_stats;  /* parse, queue and every stage ended so far */
    json_t *render_settings;
    /* render */
    scene_doc *doc; /* until it has rendered */
    job_result result;
    encode_format sync_format;
    encode_buffer sync_image; /* synchronous: encoded by the worker */
    int sync_status;
    ns_error sync_err;
    /* sweep */
    sweep *sweep;
    job_result *variants;
    int32_t current_variant;
    uint32_t variants_finished;
    /* events */
    job_event *events;
    uint32_t event_count, event_cap;
    uint64_t next_event_id;
    double last_tick_ms;
    int ended; /* the final event is in the log */
    uint64_t bytes;
    job *next; /* queue */
};

struct job_store {
    ns_context *ctx;
    char device[256];
    uint32_t capacity, ttl_s;
    uint64_t max_bytes, bytes;
    const char *asset_dir;
    uint32_t max_deadline_ms;
    char instance[JOB_INSTANCE_MAX + 1];
    pthread_mutex_t lock;
    pthread_cond_t work;    /* a job arrived, or stopping */
    pthread_cond_t changed; /* any job changed: waiters and event streams look again */
    pthread_t worker;
    job *head, *tail;
    uint32_t admitted;
    job **table; /* asynchronous jobs, in creation order */
    uint32_t table_count, table_cap;
    char (*tombstones)[JOB_ID_MAX + 1];
    uint32_t tombstone_next;
    int stopping;       /* the worker ends once the queue is empty */
    int closing;        /* job_store_shutdown ran: nothing new is admitted */
    int streams_closed; /* event streams end */
    double average_ms; /* moving average of a job's duration, for Retry-After */
    /* Work between jobs (ns_context_idle_work), once the queue has been empty for
     * JOB_IDLE_AFTER_MS: */
    int idle_work;      /* on (serve --idle-work) */
    int idle_due;       /* a job ended since idle work last found nothing to do */
    int idle_cancel;    /* set (atomically) when a job arrives: the idle call stops */
    int idle_running;   /* a call is running now */
    double idle_quiet_ms; /* the quiet before a call: doubled after a stopped one */
    uint64_t idle_nodes, idle_stopped;
    double idle_seconds;
};

static const char *const state_names[JOB_STATE_COUNT] = {"queued", "running", "done", "failed",
                                                         "cancelled"};

const char *job_state_name(job_state state)
{
    return state < JOB_STATE_COUNT ? state_names[state] : "unknown";
}

static int finished(job_state s)
{
    return s == JOB_DONE || s == JOB_FAILED || s == JOB_CANCELLED;
}

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* RFC 3339 in UTC with milliseconds, or JSON null for 0. */
static json_t *time_json(double wall)
{
    if (wall <= 0)
        return json_null();
    time_t secs = (time_t)wall;
    struct tm tm;
    gmtime_r(&secs, &tm);
    char text[40];
    size_t n = strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%S", &tm);
    snprintf(text + n, sizeof text - n, ".%03dZ", (int)((wall - (double)secs) * 1000.0));
    return json_string(text);
}

/* ---------------------------------------------------------------------------------------
 * Life of a job: references, results, events.
 * ------------------------------------------------------------------------------------- */
static void result_free(job_result *r)
{
    ns_image_free(&r->image);
    json_decref(r->error);
    r->error = NULL;
}

static void job_free(job *j)
{
    scene_doc_free(j->doc);
    result_free(&j->result);
    encode_buffer_free(&j->sync_image);
    if (j->variants)
        for (uint32_t i = 0; i < sweep_variant_count(j->sweep); i++)
            result_free(&j->variants[i]);
    free(j->variants);
    sweep_free(j->sweep);
    for (uint32_t i = 0; i < j->event_count; i++)
        free(j->events[i].data);
    free(j->events);
    json_decref(j->render_settings);
    free(j);
}

/* Called with the lock held. */
static void unref_locked(job *j)
{
    if (--j->refs == 0)
        job_free(j);
}

void job_release(job_store *store, job *j)
{
    if (!j)
        return;
    pthread_mutex_lock(&store->lock);
    unref_locked(j);
    pthread_mutex_unlock(&store->lock);
}

/* Appends an event (data consumed). Progress ticks past JOB_MAX_EVENTS are dropped; every
 * other event is kept, whatever the count, so a stream always sees its end. Lock held. */
static void add_event(job_store *store, job *j, const char *name, json_t *data, int is_tick)
{
    if (!data)
        return;
    if (is_tick && j->event_count >= JOB_MAX_EVENTS) {
        json_decref(data);
        return;
    }
    char *text = json_dumps(data, JSON_COMPACT | JSON_REAL_PRECISION(6));
    json_decref(data);
    if (!text)
        return;
    if (j->event_count == j->event_cap) {
        uint32_t cap = j->event_cap ? 2 * j->event_cap : 16;
        job_event *grown = realloc(j->events, cap * sizeof *grown);
        if (!grown) {
            free(text);
            return;
        }
        j->events = grown;
        j->event_cap = cap;
    }
    job_event *e = &j->events[j->event_count++];
    e->id = ++j->next_event_id;
    snprintf(e->name, sizeof e->name, "%s", name);
    e->data = text;
    pthread_cond_broadcast(&store->changed);
}

static uint32_t queue_position(const job_store *store, const job *j)
{
    uint32_t ahead = 0;
    for (const job *q = store->head; q && q != j; q = q->next)
        ahead++;
    return ahead;
}

/* Tells the streams of every queued job where it now stands. Lock held. */
static void announce_positions_locked(job_store *store)
{
    for (job *q = store->head; q; q = q->next)
        add_event(store, q, "state",
                  json_pack("{s:s, s:I}", "state", "queued", "queue_position",
                            (json_int_t)queue_position(store, q)),
                  0);
}

/* An absolute time ms from now on `clock`, for pthread_cond_timedwait. */
static struct timespec time_in(clockid_t clock, double ms)
{
    struct timespec t;
    clock_gettime(clock, &t);
    double ns = (double)t.tv_nsec + ms * 1e6;
    t.tv_sec += (time_t)(ns / 1e9);
    t.tv_nsec = (long)fmod(ns, 1e9);
    return t;
}

/* For waits on `changed` (the default clock). */
static struct timespec deadline_in(double ms)
{
    return time_in(CLOCK_REALTIME, ms);
}

/* ---------------------------------------------------------------------------------------
 * JSON descriptions.
 * ------------------------------------------------------------------------------------- */
/* Stage times of a job so far: parse and queue, then each stage as it ends (a sweep: summed
 * over its variants); a finished render's are its result's. */
static json_t *timings_json(const job *j)
{
    if (j->kind == JOB_RENDER && finished(j->state) && j->result.stats.stage_count)
        return render_stats_stages_json(&j->result.stats);
    return render_stats_stages_json(&j->live_stats);
}

static json_t *reused_json(const ns_render_stats *s, job_state state)
{
    json_t *list = json_array();
    if (state != JOB_DONE)
        return list;
    if (s->bvh_reused)
        json_array_append_new(list, json_string("bvh"));
    if (s->camera_reused)
        json_array_append_new(list, json_string("camera"));
    if (s->sources_reused)
        json_array_append_new(list, json_string("sources"));
    if (s->single_reused)
        json_array_append_new(list, json_string("single"));
    if (s->tables_reused > 0 && s->tables_made == 0)
        json_array_append_new(list, json_string("tables"));
    return list;
}

static json_t *variant_json(const job *j, uint32_t i)
{
    const job_result *r = &j->variants[i];
    char image[96];
    snprintf(image, sizeof image, "/v1/sweeps/%s/images/%u", j->id, i);
    json_t *v = json_pack("{s:I, s:O, s:s, s:o, s:o, s:s}", "index", (json_int_t)i, "overrides",
                          sweep_overrides(j->sweep, i), "state", job_state_name(r->state),
                          "timings_ms", render_stats_stages_json(&r->stats), "reused",
                          reused_json(&r->stats, r->state), "image", image);
    if (v && r->error)
        json_object_set(v, "error", r->error);
    return v;
}

static json_t *job_json_locked(job_store *store, job *j)
{
    const char *base = j->kind == JOB_RENDER ? "/v1/renders/" : "/v1/sweeps/";
    char self[64], events[80];
    snprintf(self, sizeof self, "%s%s", base, j->id);
    snprintf(events, sizeof events, "%s/events", self);
    json_t *links = json_pack("{s:s, s:s}", "self", self, "events", events);
    char link[96];
    if (j->kind == JOB_RENDER) {
        snprintf(link, sizeof link, "%s/image", self);
        json_object_set_new(links, "image", json_string(link));
    } else {
        snprintf(link, sizeof link, "%s/sheet.png", self);
        json_object_set_new(links, "sheet", json_string(link));
        snprintf(link, sizeof link, "%s/manifest.json", self);
        json_object_set_new(links, "manifest", json_string(link));
    }
    json_t *o = json_pack("{s:s, s:s, s:s, s:o, s:f, s:o, s:o, s:o, s:o, s:o, s:o, s:b, s:o, s:O, "
                          "s:o}",
                          "id", j->id, "kind", j->kind == JOB_RENDER ? "render" : "sweep", "state",
                          job_state_name(j->state), "queue_position",
                          j->state == JOB_QUEUED ? json_integer(queue_position(store, j))
                                                 : json_null(),
                          "progress", j->progress, "stage",
                          j->state == JOB_RUNNING && j->stage[0] ? json_string(j->stage)
                                                                 : json_null(),
                          "timings_ms", timings_json(j), "created", time_json(j->created_wall),
                          "started", time_json(j->started_wall), "finished",
                          time_json(j->finished_wall), "expires",
                          time_json(finished(j->state) ? j->finished_wall + store->ttl_s : 0),
                          "cancel_requested", j->cancel_requested, "error",
                          j->result.error ? json_incref(j->result.error) : json_null(), "render",
                          j->render_settings, "links", links);
    if (o && j->kind == JOB_SWEEP) {
        uint32_t n = sweep_variant_count(j->sweep);
        json_t *variants = json_array(), *order = json_array();
        for (uint32_t i = 0; i < n; i++) {
            json_array_append_new(variants, variant_json(j, i));
            json_array_append_new(order, json_integer(sweep_order(j->sweep)[i]));
        }
        json_object_set_new(o, "variants", variants);
        json_object_set_new(o, "order", order);
        json_object_set_new(o, "variants_finished", json_integer(j->variants_finished));
        json_object_set_new(o, "current_variant", j->current_variant >= 0
                                                       ? json_integer(j->current_variant)
                                                       : json_null());
    }
    return o;
}

json_t *job_json(job_store *store, job *j)
{
    pthread_mutex_lock(&store->lock);
    json_t *o = job_json_locked(store, j);
    pthread_mutex_unlock(&store->lock);
    return o;
}

json_t *job_manifest_json(job_store *store, job *j)
{
    pthread_mutex_lock(&store->lock);
    json_t *variants = json_array();
    for (uint32_t i = 0; j->kind == JOB_SWEEP && i < sweep_variant_count(j->sweep); i++) {
        json_t *v = variant_json(j, i);
        json_object_del(v, "image");
        json_array_append_new(variants, v);
    }
    json_t *o = json_pack("{s:s, s:s, s:O, s:o}", "id", j->id, "state", job_state_name(j->state),
                          "render", j->render_settings, "variants", variants);
    pthread_mutex_unlock(&store->lock);
    return o;
}

json_t *job_list_json(job_store *store, job_kind kind)
{
    pthread_mutex_lock(&store->lock);
    json_t *list = json_array();
    for (uint32_t i = store->table_count; i-- > 0;)
        if (store->table[i]->kind == kind)
            json_array_append_new(list, job_json_locked(store, store->table[i]));
    pthread_mutex_unlock(&store->lock);
    return list;
}

/* ---------------------------------------------------------------------------------------
 * Retention: ttl after finishing, a byte budget, and ids remembered after they go.
 * ------------------------------------------------------------------------------------- */
static void remember_gone(job_store *store, const char *id)
{
    snprintf(store->tombstones[store->tombstone_next], JOB_ID_MAX + 1, "%s", id);
    store->tombstone_next = (store->tombstone_next + 1) % TOMBSTONES;
}

static void table_remove_at(job_store *store, uint32_t index)
{
    job *j = store->table[index];
    remember_gone(store, j->id);
    store->bytes -= j->bytes;
    memmove(store->table + index, store->table + index + 1,
            (store->table_count - index - 1) * sizeof *store->table);
    store->table_count--;
    unref_locked(j);
}

/* Drops expired jobs, then the oldest finished ones while over the byte or count budget. */
static void purge_locked(job_store *store)
{
    double now = wall_now();
    uint32_t finished_count = 0;
    for (uint32_t i = 0; i < store->table_count;) {
        job *j = store->table[i];
        if (finished(j->state) && now >= j->finished_wall + store->ttl_s) {
            table_remove_at(store, i);
            continue;
        }
        finished_count += finished(j->state);
        i++;
    }
    while (store->bytes > store->max_bytes || finished_count > JOB_MAX_STORED) {
        int oldest = -1;
        for (uint32_t i = 0; i < store->table_count; i++) {
            job *j = store->table[i];
            if (finished(j->state) &&
                (oldest < 0 || j->finished_wall < store->table[oldest]->finished_wall))
                oldest = (int)i;
        }
        if (oldest < 0)
            break;
        table_remove_at(store, (uint32_t)oldest);
        finished_count--;
    }
}

/* ---------------------------------------------------------------------------------------
 * The worker: progress reports, a render, a sweep.
 * ------------------------------------------------------------------------------------- */
typedef struct progress_sink {
    job_store *store;
    job *job;
    int variant;       /* -1: a render */
    double base, span; /* the job's progress = base + span * the render's fraction */
} progress_sink;

static void on_progress(void *user, const ns_progress *p)
{
    progress_sink *sink = user;
    job_store *store = sink->store;
    job *j = sink->job;
    double now = ns_now_ms();
    pthread_mutex_lock(&store->lock);
    double fraction = sink->base + sink->span * (p->fraction < 0 ? 0 : p->fraction > 1 ? 1 : p->fraction);
    if (fraction > j->progress)
        j->progress = fraction;
    snprintf(j->stage, sizeof j->stage, "%s", p->stage ? p->stage : "");
    if (p->kind == NS_PROGRESS_STAGE_END)
        ns_stats_add_stage(&j->live_stats, j->stage, p->stage_ms);
    json_t *data = NULL;
    const char *name = NULL;
    int tick = p->kind == NS_PROGRESS_TICK;
    if (!tick || now - j->last_tick_ms >= JOB_TICK_INTERVAL_MS) {
        name = p->kind == NS_PROGRESS_STAGE_START ? "stage_start"
               : p->kind == NS_PROGRESS_STAGE_END ? "stage_end"
                                                  : "progress";
        data = json_pack("{s:s, s:f}", "stage", j->stage, "progress", j->progress);
        if (data && p->kind == NS_PROGRESS_STAGE_END)
            json_object_set_new(data, "ms", json_real(p->stage_ms));
        if (data && sink->variant >= 0)
            json_object_set_new(data, "index", json_integer(sink->variant));
        if (tick)
            j->last_tick_ms = now;
    }
    if (data)
        add_event(store, j, name, data, tick);
    pthread_mutex_unlock(&store->lock);
}

/* Renders one scene into *r, reporting progress as the part [base, base + span] of job j. */
static void render_into(job_store *store, job *j, const ns_scene *scene,
                        const ns_render_stats *before, int variant, double base, double span,
                        job_result *r)
{
    progress_sink sink = {store, j, variant, base, span};
    ns_render_control control = {.cancel = &j->cancel, .progress = on_progress, .user = &sink};
    ns_render_stats stats = *before;
    /* The service's cap on the render's deadline (--max-deadline-ms). */
    ns_scene capped = *scene;
    uint32_t cap = store->max_deadline_ms, asked = scene->render.deadline_ms;
    if (cap && (!asked || asked > cap))
        capped.render.deadline_ms = cap;
    scene = &capped;
    ns_error *err = &r->err;
    r->started_ms = ns_now_ms();
    int rc = render_job_render(store->ctx, scene, &control, &stats, &r->image, err);
    err->status = rc;
    r->finished_ms = ns_now_ms();
    r->stats = stats;
    r->scene = (ns_scene){.camera = scene->camera, .render = scene->render};
    if (rc == NS_ERR_CANCELLED) {
        r->state = JOB_CANCELLED;
    } else if (rc) {
        r->state = JOB_FAILED;
        r->error = problem_from_status(problem_kind_of_status(rc), rc,
                                       err->message[0] ? err->message : ns_status_message(rc));
    } else {
        r->state = JOB_DONE;
    }
}

static uint64_t image_bytes(const ns_image *img)
{
    return img->rgb ? (uint64_t)img->width * img->height * 3 * sizeof(float) : 0;
}

static void run_render(job_store *store, job *j)
{
    ns_render_stats before = j->parse_stats;
    ns_stats_add_stage(&before, "queue", ns_now_ms() - j->submitted_ms);
    job_result r = {0};
    render_into(store, j, scene_doc_scene(j->doc), &before, -1, 0.0, 1.0, &r);
    if (!j->async && r.state == JOB_DONE) {
        /* A synchronous answer is encoded here, on the worker, as it always was. */
        j->sync_status = render_job_encode(store->device, scene_doc_scene(j->doc), &r.image,
                                           j->sync_format, scene_doc_scene(j->doc)->render.exposure,
                                           &r.stats, &j->sync_image, &j->sync_err);
        ns_image_free(&r.image);
        if (j->sync_status)
            r.state = JOB_FAILED;
    }
    metrics_render_done(scene_doc_scene(j->doc)->render.method, r.state, &r.stats);
    pthread_mutex_lock(&store->lock);
    scene_doc_free(j->doc);
    j->doc = NULL;
    j->result = r;
    pthread_mutex_unlock(&store->lock);
}

static void run_sweep(job_store *store, job *j)
{
    uint32_t n = sweep_variant_count(j->sweep);
    const uint32_t *order = sweep_order(j->sweep);
    ns_render_stats before = j->parse_stats;
    ns_stats_add_stage(&before, "queue", ns_now_ms() - j->submitted_ms);
    int failed = 0;
    for (uint32_t k = 0; k < n; k++) {
        uint32_t i = order[k];
        pthread_mutex_lock(&store->lock);
        int cancelled = __atomic_load_n(&j->cancel, __ATOMIC_ACQUIRE);
        if (!cancelled) {
            j->current_variant = (int32_t)i;
            j->variants[i].state = JOB_RUNNING;
            add_event(store, j, "variant_start",
                      json_pack("{s:I, s:I}", "index", (json_int_t)i, "position", (json_int_t)k), 0);
        }
        pthread_mutex_unlock(&store->lock);
        if (cancelled)
            break;
        job_result r = {0};
        scene_doc *doc = NULL;
        ns_error err = {0};
        int rc = sweep_variant_scene(j->sweep, i, &doc, &err);
        if (rc) {
            r.state = JOB_FAILED;
            r.err = err;
            r.error = problem_from_status(problem_kind_of_status(rc), rc, err.message);
        } else {
            render_into(store, j, scene_doc_scene(doc), k == 0 ? &before : &(ns_render_stats){0},
                        (int)i, (double)k / n, 1.0 / n, &r);
            metrics_render_done(scene_doc_scene(doc)->render.method, r.state, &r.stats);
        }
        scene_doc_free(doc);
        pthread_mutex_lock(&store->lock);
        j->variants[i] = r;
        j->variants_finished++;
        j->current_variant = -1;
        j->bytes += image_bytes(&r.image);
        failed |= r.state == JOB_FAILED;
        json_t *v = variant_json(j, i);
        if (v) {
            json_object_del(v, "overrides");
            json_object_del(v, "image");
        }
        add_event(store, j, "variant_end", v, 0);
        pthread_mutex_unlock(&store->lock);
    }
    pthread_mutex_lock(&store->lock);
    for (uint32_t i = 0; i < n; i++)
        if (j->variants[i].state == JOB_QUEUED || j->variants[i].state == JOB_RUNNING)
            j->variants[i].state = JOB_CANCELLED;
    /* The sweep's own result: cancelled when a DELETE left variants unrendered (one that
     * came after the last variant changes nothing), else failed with the first failure's
     * problem when one failed, else done. */
    int cancelled = 0;
    for (uint32_t i = 0; i < n; i++)
        cancelled |= j->variants[i].state == JOB_CANCELLED;
    j->result.state = cancelled ? JOB_CANCELLED : failed ? JOB_FAILED : JOB_DONE;
    for (uint32_t i = 0; i < n && !cancelled && failed && !j->result.error; i++)
        if (j->variants[i].error)
            j->result.error = json_incref(j->variants[i].error);
    pthread_mutex_unlock(&store->lock);
}

/* Lock held: the job has reached a final state. */
static void finish_locked(job_store *store, job *j, job_state state)
{
    j->state = state;
    j->finished_wall = wall_now();
    j->current_variant = -1;
    if (state == JOB_DONE)
        j->progress = 1.0;
    if (state == JOB_CANCELLED && !j->result.error)
        j->result.error =
            problem_from_status(problem_kind_of_status(NS_ERR_CANCELLED), NS_ERR_CANCELLED,
                                j->started_wall > 0 ? "cancelled while running"
                                                    : "cancelled before it started");
    j->bytes += image_bytes(&j->result.image);
    if (j->async)
        store->bytes += j->bytes;
    add_event(store, j, job_state_name(state), job_json_locked(store, j), 0);
    j->ended = 1;
    pthread_cond_broadcast(&store->changed);
}

double job_idle_quiet_next_ms(double quiet_ms, int stopped)
{
    return stopped ? fmin(2.0 * quiet_ms, JOB_IDLE_AFTER_MAX_MS) : JOB_IDLE_AFTER_MS;
}

/* One call of idle work, the lock held on entry and on return (released during the call). A
 * job admitted meanwhile sets idle_cancel, so the call stops at its next device submission
 * and the job waits at most that long. */
static void idle_step_locked(job_store *store)
{
    __atomic_store_n(&store->idle_cancel, 0, __ATOMIC_RELEASE);
    store->idle_running = 1;
    pthread_mutex_unlock(&store->lock);
    double t0 = ns_now_ms();
    uint32_t made = 0;
    ns_error err = {0};
    int rc = ns_context_idle_work(store->ctx, &store->idle_cancel, &made, &err);
    double ms = ns_now_ms() - t0;
    pthread_mutex_lock(&store->lock);
    store->idle_running = 0;
    store->idle_seconds += ms / 1000.0;
    store->idle_nodes += made;
    store->idle_quiet_ms = job_idle_quiet_next_ms(store->idle_quiet_ms, rc == NS_ERR_CANCELLED);
    if (rc == NS_ERR_CANCELLED) {
        store->idle_stopped++;
    } else if (rc) {
        /* Not the next job's business: it makes its own tables if it needs them. */
        fprintf(stderr, "nscatter serve: work between renders stopped: %s\n", err.message);
        store->idle_due = 0;
    } else if (!made) {
        store->idle_due = 0;
    }
}

static void *worker_main(void *arg)
{
    job_store *store = arg;
    pthread_mutex_lock(&store->lock);
    for (;;) {
        while (!store->head && !store->stopping) {
            if (!store->idle_due || store->closing) {
                pthread_cond_wait(&store->work, &store->lock);
                continue;
            }
            struct timespec until = time_in(CLOCK_MONOTONIC, store->idle_quiet_ms);
            if (pthread_cond_timedwait(&store->work, &store->lock, &until) == ETIMEDOUT &&
                !store->head && !store->stopping && !store->closing)
                idle_step_locked(store);
        }
        job *j = store->head;
        if (!j)
            break;
        store->head = j->next;
        if (!store->head)
            store->tail = NULL;
        j->next = NULL;
        j->state = JOB_RUNNING;
        j->started_wall = wall_now();
        ns_stats_add_stage(&j->live_stats, "queue", ns_now_ms() - j->submitted_ms);
        add_event(store, j, "state", json_pack("{s:s}", "state", "running"), 0);
        announce_positions_locked(store); /* the jobs behind it moved up */
        pthread_mutex_unlock(&store->lock);

        double start = ns_now_ms();
        if (j->kind == JOB_RENDER)
            run_render(store, j);
        else
            run_sweep(store, j);
        double took = ns_now_ms() - start;

        pthread_mutex_lock(&store->lock);
        store->average_ms = store->average_ms > 0 ? 0.7 * store->average_ms + 0.3 * took : took;
        finish_locked(store, j, j->result.state);
        store->idle_due = store->idle_work;
        store->admitted--;
        purge_locked(store);
        unref_locked(j); /* the queue's reference */
    }
    pthread_mutex_unlock(&store->lock);
    return NULL;
}

/* ---------------------------------------------------------------------------------------
 * Admission.
 * ------------------------------------------------------------------------------------- */
static int new_id(const char *instance, char out[JOB_ID_MAX + 1])
{
    if (instance && *instance) {
        size_t n = strlen(instance);
        memcpy(out, instance, n);
        out[n] = '-';
        out += n + 1;
    }
    unsigned char bytes[JOB_ID_CHARS / 2];
    size_t got = 0;
    while (got < sizeof bytes) {
        ssize_t n = getrandom(bytes + got, sizeof bytes - got, 0);
        if (n <= 0)
            return -1;
        got += (size_t)n;
    }
    for (size_t i = 0; i < sizeof bytes; i++)
        snprintf(out + 2 * i, 3, "%02x", bytes[i]);
    return 0;
}

static int admit(job_store *store, job *j, uint32_t *retry_after_s)
{
    pthread_mutex_lock(&store->lock);
    if (store->admitted >= store->capacity || store->stopping || store->closing) {
        pthread_mutex_unlock(&store->lock);
        job_store_full(store, retry_after_s);
        return NS_ERR_LIMIT;
    }
    if (j->async) {
        purge_locked(store);
        if (store->table_count == store->table_cap) {
            uint32_t cap = store->table_cap ? 2 * store->table_cap : 64;
            job **grown = realloc(store->table, cap * sizeof *grown);
            if (!grown) {
                pthread_mutex_unlock(&store->lock);
                return NS_ERR_OUT_OF_HOST_MEMORY;
            }
            store->table = grown;
            store->table_cap = cap;
        }
        store->table[store->table_count++] = j;
        j->refs++;
    }
    j->refs++; /* the queue's */
    j->submitted_ms = ns_now_ms();
    j->created_wall = wall_now();
    j->live_stats = j->parse_stats;
    if (store->tail)
        store->tail->next = j;
    else
        store->head = j;
    store->tail = j;
    store->admitted++;
    __atomic_store_n(&store->idle_cancel, 1, __ATOMIC_RELEASE);
    add_event(store, j, "state",
              json_pack("{s:s, s:I}", "state", "queued", "queue_position",
                        (json_int_t)queue_position(store, j)),
              0);
    pthread_cond_signal(&store->work);
    pthread_mutex_unlock(&store->lock);
    return NS_OK;
}

/* Everything admitted must finish before a slot opens; the running one is taken as half
 * done. */
int job_store_full(job_store *store, uint32_t *retry_after_s)
{
    pthread_mutex_lock(&store->lock);
    int full = store->admitted >= store->capacity || store->closing;
    double wait_s = store->average_ms * ((double)store->admitted - 0.5) / 1000.0;
    pthread_mutex_unlock(&store->lock);
    double rounded = ceil(wait_s);
    *retry_after_s = rounded < 1.0 ? 1u : rounded > 3600.0 ? 3600u : (uint32_t)rounded;
    return full;
}

static job *job_new(const job_store *store, job_kind kind, int async, const ns_render_stats *stats)
{
    job *j = calloc(1, sizeof *j);
    if (!j)
        return NULL;
    if (new_id(store->instance, j->id)) {
        free(j);
        return NULL;
    }
    j->kind = kind;
    j->async = async;
    j->refs = 1;
    j->current_variant = -1;
    if (stats)
        j->parse_stats = *stats;
    return j;
}

int job_submit_render(job_store *store, scene_doc *doc, int async, encode_format sync_format,
                      const ns_render_stats *stats, job **out, uint32_t *retry_after_s)
{
    *out = NULL;
    job *j = job_new(store, JOB_RENDER, async, stats);
    if (j)
        j->sync_format = sync_format;
    const ns_scene *scene = scene_doc_scene(doc);
    if (j)
        j->render_settings = render_settings_json(scene, scene->render.exposure);
    if (!j || !j->render_settings) {
        if (j)
            job_free(j);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    j->doc = doc;
    int rc = admit(store, j, retry_after_s);
    if (rc) {
        j->doc = NULL; /* the caller's again */
        job_free(j);
        return rc;
    }
    *out = j;
    return NS_OK;
}

int job_submit_sweep(job_store *store, sweep *sw, const ns_render_stats *stats, job **out,
                     uint32_t *retry_after_s)
{
    *out = NULL;
    job *j = job_new(store, JOB_SWEEP, 1, stats);
    uint32_t n = sweep_variant_count(sw);
    if (j) {
        j->variants = calloc(n, sizeof *j->variants);
        scene_doc *first = NULL;
        ns_error err;
        if (j->variants && sweep_variant_scene(sw, sweep_order(sw)[0], &first, &err) == 0) {
            const ns_scene *scene = scene_doc_scene(first);
            j->render_settings = render_settings_json(scene, scene->render.exposure);
        }
        scene_doc_free(first);
    }
    if (!j || !j->variants || !j->render_settings) {
        if (j)
            job_free(j);
        return NS_ERR_OUT_OF_HOST_MEMORY;
    }
    j->sweep = sw;
    int rc = admit(store, j, retry_after_s);
    if (rc) {
        j->sweep = NULL;
        free(j->variants);
        j->variants = NULL;
        job_free(j);
        return rc;
    }
    *out = j;
    return NS_OK;
}

/* ---------------------------------------------------------------------------------------
 * Lookup, waiting, cancelling.
 * ------------------------------------------------------------------------------------- */
job *job_find(job_store *store, const char *id, job_kind kind, int *gone)
{
    *gone = 0;
    /* Ours: our instance's prefix, then 32 lower-case hex digits. */
    size_t prefix = store->instance[0] ? strlen(store->instance) + 1 : 0;
    if (prefix && (strncmp(id, store->instance, prefix - 1) || id[prefix - 1] != '-'))
        return NULL;
    if (strlen(id + prefix) != JOB_ID_CHARS ||
        strspn(id + prefix, "0123456789abcdef") != JOB_ID_CHARS)
        return NULL;
    pthread_mutex_lock(&store->lock);
    purge_locked(store);
    job *found = NULL;
    for (uint32_t i = 0; i < store->table_count; i++)
        if (!strcmp(store->table[i]->id, id) && store->table[i]->kind == kind) {
            found = store->table[i];
            found->refs++;
            break;
        }
    for (uint32_t i = 0; !found && i < TOMBSTONES; i++)
        if (!strcmp(store->tombstones[i], id)) {
            *gone = 1;
            break;
        }
    pthread_mutex_unlock(&store->lock);
    return found;
}

void job_wait(job_store *store, job *j, int (*client_gone)(void *user), void *user)
{
    pthread_mutex_lock(&store->lock);
    while (!finished(j->state)) {
        struct timespec until = deadline_in(100);
        pthread_cond_timedwait(&store->changed, &store->lock, &until);
        if (!finished(j->state) && !j->cancel_requested && client_gone) {
            pthread_mutex_unlock(&store->lock);
            int gone = client_gone(user);
            pthread_mutex_lock(&store->lock);
            if (gone && !finished(j->state) && !j->cancel_requested) {
                pthread_mutex_unlock(&store->lock);
                job_cancel(store, j);
                pthread_mutex_lock(&store->lock);
            }
        }
    }
    pthread_mutex_unlock(&store->lock);
}

job_cancel_result job_cancel(job_store *store, job *j)
{
    pthread_mutex_lock(&store->lock);
    job_cancel_result result;
    if (finished(j->state)) {
        for (uint32_t i = 0; i < store->table_count; i++)
            if (store->table[i] == j) {
                table_remove_at(store, i);
                break;
            }
        result = JOB_DISCARDED;
    } else if (j->state == JOB_QUEUED) {
        job **link = &store->head;
        job *prev = NULL;
        while (*link && *link != j) {
            prev = *link;
            link = &(*link)->next;
        }
        if (*link) {
            *link = j->next;
            if (store->tail == j)
                store->tail = prev;
            j->next = NULL;
            store->admitted--;
        }
        j->cancel_requested = 1;
        __atomic_store_n(&j->cancel, 1, __ATOMIC_RELEASE);
        if (j->kind == JOB_SWEEP)
            for (uint32_t i = 0; i < sweep_variant_count(j->sweep); i++)
                j->variants[i].state = JOB_CANCELLED;
        j->result.state = JOB_CANCELLED;
        finish_locked(store, j, JOB_CANCELLED);
        announce_positions_locked(store);
        unref_locked(j); /* the queue's reference; the caller still holds one */
        result = JOB_CANCELLED_QUEUED;
    } else {
        j->cancel_requested = 1;
        __atomic_store_n(&j->cancel, 1, __ATOMIC_RELEASE);
        add_event(store, j, "state", json_pack("{s:s, s:b}", "state", "running", "cancel_requested", 1), 0);
        result = JOB_CANCEL_REQUESTED;
    }
    pthread_cond_broadcast(&store->changed);
    pthread_mutex_unlock(&store->lock);
    return result;
}

/* ---------------------------------------------------------------------------------------
 * Results.
 * ------------------------------------------------------------------------------------- */
int job_take_sync_result(job_store *store, job *j, encode_buffer *image, ns_render_stats *stats,
                         ns_error *err)
{
    pthread_mutex_lock(&store->lock);
    *stats = j->result.stats;
    int status = NS_OK;
    if (j->result.state == JOB_DONE) {
        *image = j->sync_image;
        j->sync_image = (encode_buffer){0};
    } else if (j->result.state == JOB_CANCELLED) {
        status = ns_fail(err, NS_ERR_CANCELLED, "cancelled: the client went away");
    } else if (j->sync_status) {
        status = j->sync_status;
        *err = j->sync_err;
    } else {
        *err = j->result.err;
        status = err->status ? err->status : NS_ERR_INTERNAL;
    }
    pthread_mutex_unlock(&store->lock);
    return status;
}

int job_encode_image(job_store *store, job *j, int variant, encode_format format,
                     encode_buffer *out, ns_render_stats *stats, job_state *state, ns_error *err)
{
    pthread_mutex_lock(&store->lock);
    const job_result *r = NULL;
    if (j->kind == JOB_RENDER) {
        r = &j->result;
        *state = j->state;
    } else if (variant >= 0 && (uint32_t)variant < sweep_variant_count(j->sweep)) {
        r = &j->variants[variant];
        *state = r->state;
    } else {
        pthread_mutex_unlock(&store->lock);
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "no variant %d", variant);
    }
    /* A result, once done, never changes and is freed only with the job, which the caller
     * holds: it can be encoded without the lock. */
    int done = *state == JOB_DONE && r->image.rgb;
    pthread_mutex_unlock(&store->lock);
    if (!done)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE, "the %s is %s", variant >= 0 ? "variant" : "render",
                       job_state_name(*state));
    *stats = r->stats;
    return render_job_encode(store->device, &r->scene, &r->image, format, r->scene.render.exposure,
                             stats, out, err);
}

/* A render's own time: its stages but parsing and waiting in the queue. */
static double render_ms(const ns_render_stats *stats)
{
    double ms = 0;
    for (uint32_t i = 0; i < stats->stage_count && i < NS_MAX_STAGES; i++)
        if (strcmp(stats->stages[i].name, "parse") && strcmp(stats->stages[i].name, "queue"))
            ms += stats->stages[i].ms;
    return ms;
}

/* One cell per variant in index order: its image once done, else a placeholder with its
 * state; under it the overrides ("g=0.5") and, once done, the render time. The images are
 * read without the lock (a done variant's image never changes, and the caller holds the
 * job); the labels are made under it. */
#define SHEET_LINES 8u
int job_sweep_sheet(job_store *store, job *j, encode_buffer *out, ns_error *err)
{
    uint32_t n = sweep_variant_count(j->sweep);
    contact_sheet_cell *cells = calloc(n, sizeof *cells);
    char(*text)[SHEET_LINES][96] = calloc(n, sizeof *text);
    const char *(*lines)[SHEET_LINES] = calloc(n, sizeof *lines);
    if (!cells || !text || !lines) {
        free(cells);
        free(text);
        free(lines);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "contact sheet: %u cells", n);
    }
    /* Every variant's camera is the base scene's unless an override changes it: the
     * placeholders take the size of the variant that renders first (render_settings), and
     * the sheet its exposure. */
    json_t *settings = j->render_settings;
    uint32_t width = (uint32_t)json_integer_value(json_object_get(settings, "width"));
    uint32_t height = (uint32_t)json_integer_value(json_object_get(settings, "height"));
    float exposure = (float)json_number_value(json_object_get(settings, "exposure"));
    pthread_mutex_lock(&store->lock);
    for (uint32_t i = 0; i < n; i++) {
        const job_result *r = &j->variants[i];
        uint32_t count = sweep_label_lines(j->sweep, i, text[i], SHEET_LINES - 1);
        if (r->state == JOB_DONE)
            snprintf(text[i][count++], 96, "%.0f ms", render_ms(&r->stats));
        for (uint32_t k = 0; k < count; k++)
            lines[i][k] = text[i][k];
        int done = r->state == JOB_DONE && r->image.rgb;
        cells[i] = (contact_sheet_cell){.image = done ? &r->image : NULL,
                                        .lines = lines[i],
                                        .line_count = count,
                                        .note = done ? NULL : job_state_name(r->state),
                                        .width = width,
                                        .height = height};
    }
    pthread_mutex_unlock(&store->lock);
    int rc = contact_sheet_png(&(contact_sheet_desc){.cells = cells,
                                                     .cell_count = n,
                                                     .exposure_stops = exposure},
                               out, err);
    free(cells);
    free(text);
    free(lines);
    return rc;
}

/* ---------------------------------------------------------------------------------------
 * Event streams.
 * ------------------------------------------------------------------------------------- */
static int append_text(char **text, size_t *len, size_t *cap, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
static int append_text(char **text, size_t *len, size_t *cap, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n < 0)
        return -1;
    if (*len + (size_t)n + 1 > *cap) {
        size_t grown_cap = *cap ? *cap : 256;
        while (grown_cap < *len + (size_t)n + 1)
            grown_cap *= 2;
        char *grown = realloc(*text, grown_cap);
        if (!grown)
            return -1;
        *text = grown;
        *cap = grown_cap;
    }
    va_start(ap, fmt);
    vsnprintf(*text + *len, *cap - *len, fmt, ap);
    va_end(ap);
    *len += (size_t)n;
    return 0;
}

int job_events_wait(job_store *store, job *j, uint64_t after, double timeout_ms, char **text,
                    uint64_t *last, int *ended)
{
    *text = NULL;
    *last = after;
    *ended = 0;
    size_t len = 0, cap = 0;
    double deadline = ns_now_ms() + timeout_ms;
    pthread_mutex_lock(&store->lock);
    for (;;) {
        int have = j->event_count > 0 && j->events[j->event_count - 1].id > after;
        if (have || j->ended || store->streams_closed)
            break;
        double left = deadline - ns_now_ms();
        if (left <= 0)
            break;
        struct timespec until = deadline_in(fmin(left, 1000.0));
        pthread_cond_timedwait(&store->changed, &store->lock, &until);
    }
    int status = NS_OK;
    for (uint32_t i = 0; i < j->event_count; i++) {
        const job_event *e = &j->events[i];
        if (e->id <= after)
            continue;
        if (append_text(text, &len, &cap, "id: %llu\nevent: %s\ndata: %s\n\n",
                        (unsigned long long)e->id, e->name, e->data)) {
            status = NS_ERR_OUT_OF_HOST_MEMORY;
            break;
        }
        *last = e->id;
    }
    /* Ended when the final event has been (or is now being) sent, or the service stops. */
    *ended = store->streams_closed ||
             (j->ended && j->event_count && *last >= j->events[j->event_count - 1].id);
    pthread_mutex_unlock(&store->lock);
    if (!status && !*text && !(*text = calloc(1, 1)))
        status = NS_ERR_OUT_OF_HOST_MEMORY;
    if (status) {
        free(*text);
        *text = NULL;
    }
    return status;
}

/* ---------------------------------------------------------------------------------------
 * The store.
 * ------------------------------------------------------------------------------------- */
int job_store_create(const job_store_desc *desc, job_store **out, ns_error *err)
{
    *out = NULL;
    job_store *store = calloc(1, sizeof *store);
    if (store)
        store->tombstones = calloc(TOMBSTONES, sizeof *store->tombstones);
    if (!store || !store->tombstones) {
        free(store);
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "job store: out of memory");
    }
    store->ctx = desc->ctx;
    ns_device_info info;
    ns_context_device_info(desc->ctx, &info);
    snprintf(store->device, sizeof store->device, "%s", info.device_name);
    store->capacity = desc->capacity ? desc->capacity : 1;
    store->ttl_s = desc->ttl_s ? desc->ttl_s : JOB_DEFAULT_TTL_S;
    store->max_bytes = desc->max_bytes ? desc->max_bytes : JOB_DEFAULT_STORE_BYTES;
    store->asset_dir = desc->asset_dir;
    store->max_deadline_ms = desc->max_deadline_ms;
    store->idle_work = !desc->no_idle_work;
    store->idle_quiet_ms = JOB_IDLE_AFTER_MS;
    snprintf(store->instance, sizeof store->instance, "%s", desc->instance ? desc->instance : "");
    pthread_mutex_init(&store->lock, NULL);
    /* The worker's quiet before idle work is timed on the monotonic clock. */
    pthread_condattr_t monotonic;
    pthread_condattr_init(&monotonic);
    pthread_condattr_setclock(&monotonic, CLOCK_MONOTONIC);
    pthread_cond_init(&store->work, &monotonic);
    pthread_condattr_destroy(&monotonic);
    /* Waits on `changed` use CLOCK_REALTIME deadlines (the default clock). */
    pthread_cond_init(&store->changed, NULL);
    if (pthread_create(&store->worker, NULL, worker_main, store) != 0) {
        pthread_cond_destroy(&store->changed);
        pthread_cond_destroy(&store->work);
        pthread_mutex_destroy(&store->lock);
        free(store->tombstones);
        free(store);
        return ns_fail(err, NS_ERR_INTERNAL, "job store: cannot start the render worker");
    }
    *out = store;
    return NS_OK;
}

void job_store_shutdown(job_store *store)
{
    if (!store)
        return;
    pthread_mutex_lock(&store->lock);
    store->closing = 1;
    __atomic_store_n(&store->idle_cancel, 1, __ATOMIC_RELEASE); /* a drain waits for no idle work */
    /* At most `capacity` jobs are unfinished, and `nscatter serve --queue` is at most 1024. */
    job *cancel[1024];
    uint32_t n = 0;
    for (uint32_t i = 0; i < store->table_count && n < 1024; i++)
        if (!finished(store->table[i]->state)) {
            cancel[n++] = store->table[i];
            store->table[i]->refs++;
        }
    pthread_mutex_unlock(&store->lock);
    for (uint32_t i = 0; i < n; i++) {
        job_cancel(store, cancel[i]);
        job_release(store, cancel[i]);
    }
    pthread_mutex_lock(&store->lock);
    store->streams_closed = 1;
    pthread_cond_broadcast(&store->changed);
    pthread_mutex_unlock(&store->lock);
}

void job_store_count(job_store *store, job_store_counts *out)
{
    memset(out, 0, sizeof *out);
    pthread_mutex_lock(&store->lock);
    purge_locked(store);
    out->admitted = store->admitted;
    for (uint32_t i = 0; i < store->table_count; i++)
        out->by_state[store->table[i]->state]++;
    out->bytes = store->bytes;
    out->idle_pending = store->idle_due && !store->closing;
    out->idle_running = store->idle_running;
    out->idle_nodes = store->idle_nodes;
    out->idle_stopped = store->idle_stopped;
    out->idle_seconds = store->idle_seconds;
    pthread_mutex_unlock(&store->lock);
}

void job_store_destroy(job_store *store)
{
    if (!store)
        return;
    job_store_shutdown(store);
    pthread_mutex_lock(&store->lock);
    store->stopping = 1;
    pthread_cond_signal(&store->work);
    pthread_mutex_unlock(&store->lock);
    pthread_join(store->worker, NULL);
    pthread_mutex_lock(&store->lock);
    while (store->table_count)
        table_remove_at(store, store->table_count - 1);
    pthread_mutex_unlock(&store->lock);
    free(store->table);
    free(store->tombstones);
    pthread_cond_destroy(&store->changed);
    pthread_cond_destroy(&store->work);
    pthread_mutex_destroy(&store->lock);
    free(store);
}
