/* progress.c — progress reports and cancellation of the render in progress (internal.h says
 * how the fraction is planned; nscatter.h what a caller sees).
 *
 * Everything here runs on the rendering thread with the context's lock held; the only thing
 * another thread touches is the caller's cancellation flag, read with an acquire load: by
 * the device layer before every submission (gpu_cancel_check), at the points between stages
 * that ns_run_check marks, and here around every report. Once the flag was seen set
 * (dev.cancelled), nothing new is reported: no START, no TICK, only the ENDs of the stages
 * the render unwinds through, and the fraction stays where it was. */
#include <stdio.h>
#include <string.h>

#include "internal.h"

static double clamp01(double x)
{
    return x < 0.0 ? 0.0 : x > 1.0 ? 1.0 : x;
}

/* The point `part` of the way through span s; exactly s.hi at the end, so that the last
 * stage's END reports exactly 1. */
static double span_at(ns_span s, double part)
{
    part = clamp01(part);
    return part >= 1.0 ? s.hi : s.lo + part * (s.hi - s.lo);
}

/* Where the render was when a cancellation was first noticed, for its message. */
static void note_cancel(ns_run *run)
{
    if (run->where[0])
        return;
    if (run->stage)
        snprintf(run->where, sizeof run->where, "during %s", run->stage);
    else if (run->last)
        snprintf(run->where, sizeof run->where, "after %s", run->last);
    else
        snprintf(run->where, sizeof run->where, "before the first stage");
}

/* Whether the render has seen its cancellation flag set: then it reports nothing new and
 * ends with NS_ERR_CANCELLED (ns_run_end), even where no check stops it first. Looked at
 * before every report and after every callback, so that a callback that sets the flag sees
 * no START or TICK after that. */
static int cancel_seen(ns_context *ctx)
{
    if (ctx->dev.cancelled)
        return 1;
    if (ctx->dev.deadline_ms > 0 && ns_now_ms() >= ctx->dev.deadline_ms)
        ctx->dev.deadline_hit = 1;
    else if (!ctx->dev.cancel || !__atomic_load_n(ctx->dev.cancel, __ATOMIC_ACQUIRE))
        return 0;
    ctx->dev.cancelled = 1;
    note_cancel(&ctx->run);
    return 1;
}

static int reporting(ns_context *ctx)
{
    const ns_render_control *c = ctx->run.control;
    return c && c->progress && !cancel_seen(ctx);
}

static void report(ns_context *ctx, ns_progress_kind kind, const char *stage, double fraction,
                   double stage_ms)
{
    ns_run *run = &ctx->run;
    fraction = clamp01(fraction);
    if (fraction > run->done)
        run->done = fraction;
    ns_progress p = {.kind = kind, .stage = stage, .fraction = run->done, .stage_ms = stage_ms};
    run->control->progress(run->control->user, &p);
    (void)cancel_seen(ctx);
}

void ns_run_begin(ns_context *ctx, const ns_render_control *control, uint32_t deadline_ms)
{
    ns_run *run = &ctx->run;
    uint64_t serial = run->serial + 1;
    memset(run, 0, sizeof *run);
    run->serial = serial;
    run->control = control;
    run->span = (ns_span){0.0, 1.0};
    ctx->dev.cancel = control ? control->cancel : NULL;
    ctx->dev.cancelled = 0;
    run->deadline_ms = deadline_ms;
    ctx->dev.deadline_ms = deadline_ms ? ns_now_ms() + deadline_ms : 0;
    ctx->dev.deadline_hit = 0;
}

int ns_run_end(ns_context *ctx, int status, ns_error *err)
{
    ns_run *run = &ctx->run;
    /* The flag seen set cancels, also where no check came after it (seen by a report after
     * the last submission): what is reported and what is returned agree. */
    if (ctx->dev.cancelled && status == NS_OK)
        status = NS_ERR_CANCELLED;
    if (status == NS_ERR_CANCELLED) {
        note_cancel(run);
        /* A deadline stops the render the way a cancellation does; the caller hears which. */
        if (ctx->dev.deadline_hit)
            status = ns_fail(err, NS_ERR_DEADLINE,
                             "render.deadline_ms: the render ran past its deadline of %u ms and "
                             "stopped %s",
                             run->deadline_ms, run->where);
        else
            ns_fail(err, NS_ERR_CANCELLED, "cancelled %s", run->where);
    }
    ctx->dev.cancel = NULL;
    ctx->dev.cancelled = 0;
    ctx->dev.deadline_ms = 0;
    ctx->dev.deadline_hit = 0;
    run->control = NULL;
    run->stage = run->last = NULL;
    return status;
}

int ns_run_check(ns_context *ctx, ns_error *err)
{
    int status = gpu_cancel_check(&ctx->dev, err);
    if (status)
        note_cancel(&ctx->run);
    return status;
}

ns_span ns_progress_push(ns_context *ctx, double a, double b)
{
    ns_span outer = ctx->run.span;
    ctx->run.span = (ns_span){span_at(outer, a), span_at(outer, b)};
    return outer;
}

void ns_progress_pop(ns_context *ctx, ns_span outer)
{
    ns_run *run = &ctx->run;
    if (!ctx->dev.cancelled && run->span.hi > run->done)
        run->done = run->span.hi;
    run->span = outer;
}

void ns_progress_restore(ns_context *ctx, ns_span outer)
{
    ctx->run.span = outer;
}

int ns_progress_wanted(ns_context *ctx)
{
    return reporting(ctx);
}

void ns_progress_tick(ns_context *ctx, double part)
{
    if (!reporting(ctx))
        return;
    const ns_run *run = &ctx->run;
    report(ctx, NS_PROGRESS_TICK,
           run->stage  ? run->stage
           : run->last ? run->last
                       : "",
           span_at(run->span, part), 0.0);
}

ns_stage ns_stage_begin(ns_context *ctx, const char *name, double a, double b)
{
    ns_stage stage = {.name = name, .outer = ns_progress_push(ctx, a, b)};
    ctx->run.stage = name;
    stage.reported = reporting(ctx);
    if (stage.reported)
        report(ctx, NS_PROGRESS_STAGE_START, name, ctx->run.span.lo, 0.0);
    stage.t0 = ns_now_ms(); /* after the callback: its time is not the stage's */
    return stage;
}

double ns_stage_end(ns_context *ctx, const ns_stage *stage)
{
    double ms = ns_now_ms() - stage->t0;
    ns_run *run = &ctx->run;
    if (ctx->dev.cancelled)
        note_cancel(run); /* a submission of this stage was refused */
    ns_progress_pop(ctx, stage->outer);
    run->stage = NULL;
    run->last = stage->name;
    if (stage->reported)
        report(ctx, NS_PROGRESS_STAGE_END, stage->name, run->done, ms);
    return ms;
}
