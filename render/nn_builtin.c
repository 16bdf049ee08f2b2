/* nn_builtin.c — the committed weights (weights/double.bin, weights/multiple.bin) built
 * into the binary, so a deployed binary never depends on its source tree. CMake defines
 * NS_NN_WEIGHTS_DOUBLE / _MULTIPLE to the files' absolute paths when they exist and makes
 * this file recompile when they change. The bytes are validated like a file on every load,
 * so a corrupted build is an error, not a garbage image. */
#include "nn_weights.h"

#include "gpu.h" /* ns_fail */

/* .incbin keeps the bytes out of a generated C array (no generator step, no huge source). */
#define NN_EMBED(sym, path)                                                                        \
    __asm__(".section .rodata\n.balign 16\n.global " #sym "\n.hidden " #sym "\n" #sym              \
            ":\n.incbin \"" path "\"\n.global " #sym "_end\n.hidden " #sym "_end\n" #sym           \
            "_end:\n.previous\n");                                                                 \
    extern const unsigned char sym[], sym##_end[];

#ifdef NS_NN_WEIGHTS_DOUBLE
NN_EMBED(ns_nn_blob_double, NS_NN_WEIGHTS_DOUBLE)
#endif
#ifdef NS_NN_WEIGHTS_MULTIPLE
NN_EMBED(ns_nn_blob_multiple, NS_NN_WEIGHTS_MULTIPLE)
#endif

int ns_nn_weights_builtin(uint32_t order, ns_nn_weights *w, ns_error *err)
{
    const unsigned char *begin = NULL, *end = NULL;
#ifdef NS_NN_WEIGHTS_DOUBLE
    if (order == 0)
        begin = ns_nn_blob_double, end = ns_nn_blob_double_end;
#endif
#ifdef NS_NN_WEIGHTS_MULTIPLE
    if (order == 1)
        begin = ns_nn_blob_multiple, end = ns_nn_blob_multiple_end;
#endif
    if (order > 1)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "weights: order %u out of range", order);
    if (!begin)
        return ns_fail(err, NS_ERR_NOT_AVAILABLE,
                       "this binary was built without weights/%s.bin (train them with `nscatter "
                       "train`, or pass --weights)",
                       order ? "multiple" : "double");
    int status = ns_nn_weights_parse(
        begin, (size_t)(end - begin),
        order ? "built-in weights/multiple.bin" : "built-in weights/double.bin", w, err);
    if (!status && w->h.order != order)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "built-in weights/%s.bin holds the %s network",
                       order ? "multiple" : "double", w->h.order ? "multiple" : "double");
    return status;
}
