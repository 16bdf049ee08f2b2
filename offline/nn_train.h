/* nn_train.h — mini-batch gradient descent (Adam) for the 6->50->50->1 tanh network of
 * render/include/nn_weights.h, with the matrix products in OpenBLAS. The loss is the mean squared
 * error between the network output and the (already transformed) target. */
#ifndef NS_NN_TRAIN_H
#define NS_NN_TRAIN_H

#include <stdint.h>

#include "nn_weights.h"

typedef struct ns_nn_trainer {
    uint32_t batch_cap;
    float *h1, *h2, *y, *d1, *d2; /* activations and their gradients, batch_cap rows */
    float grad[NS_NN_PARAMS];
    float m[NS_NN_PARAMS], v[NS_NN_PARAMS]; /* Adam moments */
    uint64_t step;
    float beta1, beta2, adam_eps;
} ns_nn_trainer;

int ns_nn_trainer_init(ns_nn_trainer *t, uint32_t batch_cap);
void ns_nn_trainer_free(ns_nn_trainer *t);

/* Xavier-uniform weights, zero biases, from a 64-bit seed. */
void ns_nn_init_params(float p[NS_NN_PARAMS], uint64_t seed);

/* Forward pass over n rows of x (n x 6, row-major) into t->y; returns the mean squared
 * error against target when target is not NULL. */
double ns_nn_batch_forward(ns_nn_trainer *t, const float *p, const float *x, uint32_t n,
                           const float *target);
/* Forward + backward: the loss, with its gradient in t->grad. */
double ns_nn_batch_gradient(ns_nn_trainer *t, const float *p, const float *x, const float *target,
                            uint32_t n);
/* One Adam step with learning rate lr on p from t->grad. */
void ns_nn_adam_step(ns_nn_trainer *t, float *p, float lr);

#endif
