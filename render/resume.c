/* resume.c — one round of resumed dispatches (internal.h says why lavapipe needs them):
 * submissions of dispatches until the shader reports no work left, each submission twice as
 * long as the last (up to a cap), so that a pass that needs one dispatch pays for one, and a
 * pass that needs thousands does not pay thousands of submissions. */
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* A submission of resumed dispatches grows while it takes less than this. */
#define NS_RESUME_SUBMISSION_MS 250.0

static int check_desc(const ns_resume_desc *d, ns_error *err)
{
    uint32_t size = d->pipeline->push_constant_size;
    int consistent = d->report_offset != NS_NONE
                         ? d->push_count == 1 && d->max_batch > 0 &&
                               (uint64_t)d->report_offset + sizeof(uint32_t) <= size
                         : d->push_count > 0 && d->unfinished == NS_NONE;
    if (!consistent || !d->push || !d->counters)
        return ns_fail(err, NS_ERR_INTERNAL, "%s: resumed dispatches described inconsistently",
                       d->pipeline->name);
    return NS_OK;
}

/* The part of the round done after `submissions` submissions of `round` dispatches in all
 * (internal.h, ns_resume_desc.done). */
static double round_done(const ns_resume_desc *d, uint64_t round, uint32_t submissions)
{
    if (d->done)
        return d->done(d->done_user);
    if (d->unfinished == NS_NONE)
        return 1.0;
    if (d->expected_dispatches)
        return (double)round / (double)d->expected_dispatches;
    return 1.0 - 1.0 / (1.0 + submissions);
}

int ns_resume_dispatch(ns_context *ctx, const ns_resume_desc *d, uint32_t *dispatches,
                       ns_error *err)
{
    int status = check_desc(d, err);
    if (status)
        return status;
    uint32_t size = d->pipeline->push_constant_size;
    int repeated = d->report_offset != NS_NONE;
    uint32_t batch = d->push_count;
    uint8_t *blocks = NULL;
    if (repeated) {
        batch = d->first_batch ? d->first_batch : 1;
        batch = batch < d->max_batch ? batch : d->max_batch;
        blocks = malloc((size_t)size * d->max_batch);
        if (!blocks)
            return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "%s: %u push blocks", d->pipeline->name,
                           d->max_batch);
    }
    uint64_t round = 0;
    for (uint32_t submissions = 0;; submissions++) {
        if ((d->max_submissions && submissions >= d->max_submissions) ||
            (d->max_dispatches && round >= d->max_dispatches)) {
            status = NS_RESUME_GAVE_UP;
            break;
        }
        /* Only the last dispatch of a submission reports: the shader then counts the work
         * left once, after every dispatch before it has run. */
        for (uint32_t i = 0; repeated && i < batch; i++) {
            uint32_t report = i + 1 == batch;
            memcpy(blocks + (size_t)size * i, d->push, size);
            memcpy(blocks + (size_t)size * i + d->report_offset, &report, sizeof report);
        }
        /* The previous submission has completed (gpu_dispatch_many waits for its fence), and
         * the next one makes these host writes visible to the shader. */
        double submitted_ms = ns_now_ms();
        if (d->unfinished != NS_NONE)
            d->counters[d->unfinished] = 0;
        if (d->cut != NS_NONE)
            d->counters[d->cut] = 0;
        status = gpu_dispatch_many(&ctx->dev,
                                   &(gpu_dispatch_desc){
                                       .pipeline = d->pipeline,
                                       .buffers = d->buffers,
                                       .buffer_count = d->pipeline->binding_count,
                                       .groups = {d->groups[0], d->groups[1], d->groups[2]},
                                       .push = repeated ? (const void *)blocks : d->push,
                                       .dispatch_count = batch,
                                   },
                                   err);
        round += batch;
        if (dispatches)
            *dispatches += batch;
        if (!status && d->cut != NS_NONE && d->counters[d->cut])
            status = NS_RESUME_CUT;
        if (!status && d->check)
            status = d->check(d->counters, d->user, err);
        if (!status && ns_progress_wanted(ctx))
            ns_progress_tick(ctx, round_done(d, round, submissions + 1));
        if (status || d->unfinished == NS_NONE || d->counters[d->unfinished] == 0)
            break;
        /* More work than the last submission finished: make the next one longer, but only
         * while a submission stays short, so that a cancellation or a deadline (checked
         * before each submission) is seen within about NS_RESUME_SUBMISSION_MS. How the
         * dispatches are grouped into submissions changes nothing they compute. */
        double took_ms = ns_now_ms() - submitted_ms;
        if (took_ms < NS_RESUME_SUBMISSION_MS)
            batch = 2 * batch < d->max_batch ? 2 * batch : d->max_batch;
        else if (took_ms > 2 * NS_RESUME_SUBMISSION_MS && batch > 1)
            batch /= 2;
    }
    free(blocks);
    return status;
}
