/* nn_session.c — device + pipeline + networks behind the opaque handle of render/include/nn.h. */
#include <stdlib.h>
#include <string.h>

#include "nn.h"
#include "nn_reconstruct.h"

struct ns_nn_session {
    gpu_device dev;
    ns_nn_gpu nn;
    ns_nn_weights nets[2];
    int have_dev;
};

static int load_nets(ns_nn_session *s, const ns_nn_session_desc *desc, ns_error *err)
{
    for (uint32_t o = 0; o < 2; o++) {
        const char *path = desc->weights[o];
        int status = path ? ns_nn_weights_load(path, &s->nets[o], err)
                          : ns_nn_weights_builtin(o, &s->nets[o], err);
        if (status)
            return status;
        if (s->nets[o].h.order != o)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: holds the %s network, not the %s",
                           path ? path : "built-in weights", o ? "double" : "multiple",
                           o ? "multiple" : "double");
    }
    return 0;
}

int ns_nn_session_create(const ns_nn_session_desc *desc, ns_nn_session **out, ns_error *err)
{
    *out = NULL;
    ns_nn_session *s = calloc(1, sizeof *s);
    if (!s)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "nn session: out of memory");
    int status = load_nets(s, desc, err);
    if (!status) {
        const char *device = desc->device ? desc->device : getenv("NSCATTER_DEVICE");
        status = gpu_device_create(
            &s->dev, &(gpu_device_desc){.device = device, .validation = desc->validation}, err);
        s->have_dev = status == 0;
    }
    if (!status)
        status = ns_nn_gpu_create(&s->dev, &s->nn, err);
    if (status) {
        ns_nn_session_destroy(s);
        return status;
    }
    *out = s;
    return 0;
}

void ns_nn_session_destroy(ns_nn_session *s)
{
    if (!s)
        return;
    if (s->have_dev) {
        ns_nn_gpu_destroy(&s->dev, &s->nn);
        gpu_device_destroy(&s->dev);
    }
    free(s);
}

const char *ns_nn_session_device(const ns_nn_session *s)
{
    return s->dev.info.device_name;
}

const ns_nn_weights *ns_nn_session_net(const ns_nn_session *s, uint32_t order)
{
    return order < 2 ? &s->nets[order] : NULL;
}

int ns_nn_session_reconstruct(ns_nn_session *s, const ns_nn_reconstruct_desc *desc,
                              ns_nn_reconstruct_stats *stats, ns_error *err)
{
    ns_nn_reconstruct_desc d = *desc;
    if (!d.nets[0] && !d.nets[1]) {
        d.nets[0] = &s->nets[0];
        d.nets[1] = &s->nets[1];
    }
    return ns_nn_reconstruct(&s->dev, &s->nn, &d, stats, err);
}
