/* unit_nn_weights.c — the network's weights file (validation of size, architecture and
 * checksums), its input normalisation, the CPU forward pass against the trainer's batched
 * OpenBLAS pass, the trainer's gradient against finite differences, and that Adam fits a
 * known function. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mc.h"
#include "nn_train.h"
#include "train.h"
#include "harness.h"
#include "nn_weights.h"

static ns_nn_weights random_net(uint32_t order, uint64_t seed)
{
    ns_nn_weights w;
    ns_nn_header_init(&w.h, order, NS_NN_TARGET_LOGREL);
    ns_nn_init_params(w.p, seed);
    for (int i = 0; i < NS_NN_HIDDEN; i++) /* non-zero biases exercise their paths too */
        w.p[NS_NN_OFF_B1 + i] = 0.01f * (float)(i % 7), w.p[NS_NN_OFF_B2 + i] = -0.02f * (i % 5);
    w.p[NS_NN_OFF_B3] = 0.3f;
    return w;
}

static char tmp_path[256];

static void write_bytes(const void *data, size_t n)
{
    FILE *f = fopen(tmp_path, "wb");
    fwrite(data, 1, n, f);
    fclose(f);
}

static size_t read_bytes(unsigned char *buf, size_t cap)
{
    FILE *f = fopen(tmp_path, "rb");
    size_t n = fread(buf, 1, cap, f);
    fclose(f);
    return n;
}

static void test_roundtrip(void)
{
    ns_nn_weights w = random_net(1, 5), back;
    ns_error err = {0};
    CHECK_INT(ns_nn_weights_save(&w, tmp_path, &err), 0);
    CHECK_INT(ns_nn_weights_load(tmp_path, &back, &err), 0);
    CHECK(memcmp(w.p, back.p, sizeof w.p) == 0);
    CHECK_INT(back.h.order, 1);
    unsigned char buf[20000];
    size_t n = read_bytes(buf, sizeof buf);
    CHECK_INT(n, NS_NN_HEADER_SIZE + NS_NN_PARAMS * 4);
    CHECK(n <= 12288);
}

static void expect_error(const unsigned char *buf, size_t n, const char *needle)
{
    ns_nn_weights w;
    ns_error err = {0};
    write_bytes(buf, n);
    CHECK_INT(ns_nn_weights_load(tmp_path, &w, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, needle);
    CHECK_STR_CONTAINS(err.message, tmp_path); /* the message names the file */
}

static void test_rejects_bad_files(void)
{
    ns_nn_weights w = random_net(0, 9);
    ns_error err = {0};
    CHECK_INT(ns_nn_weights_save(&w, tmp_path, &err), 0);
    unsigned char good[20000], buf[20000];
    size_t n = read_bytes(good, sizeof good);

    expect_error(good, n - 1, "truncated");
    expect_error(good, 40, "truncated");
    expect_error(good, 0, "truncated");
    memcpy(buf, good, n);
    buf[n] = 0;
    expect_error(buf, n + 1, "oversized");

    memcpy(buf, good, n);
    buf[NS_NN_HEADER_SIZE + 1000] ^= 0x10; /* one bit of one parameter */
    expect_error(buf, n, "checksum");

    memcpy(buf, good, n);
    buf[12] ^= 1; /* header_size: the header CRC catches it too, but version check first */
    expect_error(buf, n, "version");

    memcpy(buf, good, n);
    buf[0] = 'X';
    expect_error(buf, n, "magic");

    /* A foreign architecture with a valid header checksum: the architecture check names it. */
    ns_nn_header h;
    memcpy(&h, good, sizeof h);
    h.hidden1 = 40;
    h.header_crc32 = ns_crc32(&h, offsetof(ns_nn_header, header_crc32));
    memcpy(buf, good, n);
    memcpy(buf, &h, sizeof h);
    expect_error(buf, n, "architecture");

    /* Input map 2 needs g_max < 1 (ln(1 - g_max)); an unknown map number is refused. */
    memcpy(&h, good, sizeof h);
    h.input_map = NS_NN_INPUT_MAP_ASINH_LOGG;
    h.g_max = 1.0f;
    h.header_crc32 = ns_crc32(&h, offsetof(ns_nn_header, header_crc32));
    memcpy(buf, &h, sizeof h);
    expect_error(buf, n, "normalisation");
    h.input_map = 3;
    h.g_max = 0.99f;
    h.header_crc32 = ns_crc32(&h, offsetof(ns_nn_header, header_crc32));
    memcpy(buf, &h, sizeof h);
    expect_error(buf, n, "input map 3");

    /* A flipped header byte without a fixed CRC. */
    memcpy(buf, good, n);
    buf[offsetof(ns_nn_header, target_mean)] ^= 0x40;
    expect_error(buf, n, "header checksum");

    /* Missing file: an I/O error naming it. */
    unlink(tmp_path);
    CHECK_INT(ns_nn_weights_load(tmp_path, &w, &err), NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, tmp_path);
}

static void test_builtin_weights(void)
{
    /* Either the binary embeds valid weights of the right order, or it says clearly that it
     * was built without them; never garbage. */
    for (uint32_t o = 0; o < 2; o++) {
        ns_nn_weights w;
        ns_error err = {0};
        int rc = ns_nn_weights_builtin(o, &w, &err);
        if (rc == 0) {
            CHECK_INT(w.h.order, o);
            CHECK_INT(w.h.param_count, NS_NN_PARAMS);
        } else {
            CHECK_INT(rc, NS_ERR_NOT_AVAILABLE);
            CHECK_STR_CONTAINS(err.message, "built without");
        }
    }
}

static void test_normalisation(void)
{
    ns_nn_header h;
    ns_nn_header_init(&h, 0, NS_NN_TARGET_LOGREL);
    h.extent = (float)NS_TABLE_EXTENT; /* train sets it from the tables it reads */
    ns_table t;
    const uint32_t n[4] = {NS_TABLE_NZ, NS_TABLE_NRHO, NS_TABLE_NTHETA, NS_TABLE_NPHI};
    CHECK_INT(ns_table_create(&t, n, NULL), 0);
    ns_mc_default_edges(&t);
    /* The asinh map undoes the sinh bins: bin centres land nearly evenly spaced in [0, 1]. */
    float prev = -1;
    double min_step = 1, max_step = 0;
    for (uint32_t i = 0; i < n[1]; i++) {
        float x = ns_nn_map_rho(&h, 0.5 * (t.edges[1][i] + t.edges[1][i + 1]));
        CHECK(x > prev && x >= 0 && x <= 1);
        if (i > 0) {
            min_step = fmin(min_step, x - prev);
            max_step = fmax(max_step, x - prev);
        }
        prev = x;
    }
    CHECK(max_step < 3 * min_step);
    CHECK_NEAR(ns_nn_map_z(&h, 0.0), 0.5, 1e-7);
    CHECK_NEAR(ns_nn_map_z(&h, -NS_TABLE_EXTENT), 0.0, 1e-6);
    CHECK_NEAR(ns_nn_map_z(&h, NS_TABLE_EXTENT), 1.0, 1e-6);
    CHECK_NEAR(ns_nn_map_albedo(&h, 0.999), 1.0, 1e-5);
    CHECK_NEAR(ns_nn_map_albedo(&h, 0.0), 0.0, 1e-7);
    CHECK(ns_nn_map_albedo(&h, 0.9) > 0.3); /* the high-albedo end gets most of the range */
    /* g: map 1 linear; map 2 the mean of linear and ln(1 - g) / ln(1 - g_max). */
    CHECK_NEAR(ns_nn_map_g(&h, 0.45), 0.45, 1e-7);
    ns_nn_header hg = h;
    hg.input_map = NS_NN_INPUT_MAP_ASINH_LOGG;
    hg.g_max = 0.99f;
    CHECK_NEAR(ns_nn_map_g(&hg, 0.0), 0.0, 1e-7);
    CHECK_NEAR(ns_nn_map_g(&hg, 0.99), 1.0, 1e-6);
    CHECK_NEAR(ns_nn_map_g(&hg, 0.9), 0.5 * 0.9 / 0.99f + 0.5 * log(0.1) / log(1 - 0.99f), 1e-6);
    CHECK(ns_nn_map_g(&hg, 0.99) - ns_nn_map_g(&hg, 0.9) > 0.29); /* linear: 0.09 */
    CHECK_NEAR(ns_nn_map_g(&hg, 0.999), 1.0, 1e-7); /* beyond g_max: clamped, not NaN */
    CHECK_NEAR(ns_nn_map_g(&hg, 1.0), 1.0, 1e-7);
    CHECK_NEAR(ns_nn_map_g(&hg, -0.5), 0.0, 1e-7);
    ns_table_free(&t);
    /* The target transform round-trips. */
    for (int target = 0; target < 2; target++) {
        ns_nn_header_init(&h, 1, (ns_nn_target)target);
        h.target_mean = -3, h.target_scale = 2;
        double j = 0.0123, e = 0.7;
        CHECK_REL(ns_nn_output_to_j(&h, ns_nn_j_to_target(&h, j, e), e), j, 1e-9);
    }
}

static void random_inputs(float *x, uint32_t n, uint64_t seed)
{
    for (size_t i = 0; i < (size_t)n * NS_NN_INPUTS; i++) {
        seed = seed * 6364136223846793005ull + 1442695040888963407ull;
        x[i] = (float)((seed >> 40) * 0x1.0p-24);
    }
}

static void test_forward_matches_blas(void)
{
    ns_nn_weights w = random_net(0, 3);
    enum { N = 1000 };
    static float x[N * NS_NN_INPUTS];
    random_inputs(x, N, 11);
    ns_nn_trainer tr;
    CHECK_INT(ns_nn_trainer_init(&tr, N), 0);
    ns_nn_batch_forward(&tr, w.p, x, N, NULL);
    double worst = 0;
    for (int i = 0; i < N; i++) {
        double y = ns_nn_forward(&w, x + i * NS_NN_INPUTS);
        worst = fmax(worst, fabs(y - tr.y[i]) / fmax(1.0, fabs(y)));
    }
    CHECK(worst < 2e-5); /* the trainer's tanh is an expf form, the forward pass tanhf */
    ns_nn_trainer_free(&tr);
}

static void test_gradient_finite_differences(void)
{
    ns_nn_weights w = random_net(0, 21);
    enum { N = 64 };
    float x[N * NS_NN_INPUTS], t[N];
    random_inputs(x, N, 5);
    for (int i = 0; i < N; i++)
        t[i] = sinf(3 * x[i * NS_NN_INPUTS]) + x[i * NS_NN_INPUTS + 5];
    ns_nn_trainer tr;
    CHECK_INT(ns_nn_trainer_init(&tr, N), 0);
    ns_nn_batch_gradient(&tr, w.p, x, t, N);
    float grad[NS_NN_PARAMS];
    memcpy(grad, tr.grad, sizeof grad);
    const int probes[] = {
        0,           7, NS_NN_OFF_B1 + 3, NS_NN_OFF_W2 + 101, NS_NN_OFF_B2 + 49, NS_NN_OFF_W3 + 12,
        NS_NN_OFF_B3};
    for (size_t k = 0; k < sizeof probes / sizeof probes[0]; k++) {
        int i = probes[k];
        float keep = w.p[i], h = 1e-2f;
        w.p[i] = keep + h;
        double up = ns_nn_batch_forward(&tr, w.p, x, N, t);
        w.p[i] = keep - h;
        double down = ns_nn_batch_forward(&tr, w.p, x, N, t);
        w.p[i] = keep;
        double fd = (up - down) / (2 * h);
        CHECK_NEAR(grad[i], fd, 2e-3 * fmax(fabs(fd), 0.05));
    }
    ns_nn_trainer_free(&tr);
}

static void test_adam_fits_a_function(void)
{
    enum { N = 2048 };
    static float x[N * NS_NN_INPUTS], t[N];
    random_inputs(x, N, 77);
    for (int i = 0; i < N; i++) {
        const float *xi = x + i * NS_NN_INPUTS;
        t[i] = expf(-4 * xi[0]) * cosf(2 * xi[2]) + 0.5f * xi[5] * xi[4];
    }
    float p[NS_NN_PARAMS];
    ns_nn_init_params(p, 1);
    ns_nn_trainer tr;
    CHECK_INT(ns_nn_trainer_init(&tr, 256), 0);
    double first = ns_nn_batch_forward(&tr, p, x, 256, t), last = 0;
    for (int step = 0; step < 1500; step++) {
        int b = (step % (N / 256)) * 256;
        ns_nn_batch_gradient(&tr, p, x + b * NS_NN_INPUTS, t + b, 256);
        ns_nn_adam_step(&tr, p, 3e-3f);
    }
    ns_nn_trainer tr_all;
    CHECK_INT(ns_nn_trainer_init(&tr_all, N), 0);
    last = ns_nn_batch_forward(&tr_all, p, x, N, t);
    CHECK(last < first / 50);
    CHECK(last < 2e-3);
    ns_nn_trainer_free(&tr);
    ns_nn_trainer_free(&tr_all);
}

static void test_table_names(void)
{
    double g, a;
    ns_order o;
    CHECK_INT(ns_train_parse_table_name("g0.30_a0.900_multiple.json", &g, &a, &o), 0);
    CHECK_NEAR(g, 0.3, 1e-12);
    CHECK_NEAR(a, 0.9, 1e-12);
    CHECK_INT(o, NS_ORDER_MULTIPLE);
    CHECK_INT(ns_train_parse_table_name("g0.30_a0.900_multiple.npy", &g, &a, &o), -1);
    CHECK_INT(ns_train_parse_table_name("g0.30_a0.900_triple.json", &g, &a, &o), -1);
    CHECK_INT(ns_train_parse_table_name("g0.30_a0.900_double.json.part", &g, &a, &o), -1);
}

int main(void)
{
    snprintf(tmp_path, sizeof tmp_path, "/tmp/unit_nn_weights_%d.bin", (int)getpid());
    RUN(test_roundtrip);
    RUN(test_rejects_bad_files);
    RUN(test_builtin_weights);
    RUN(test_normalisation);
    RUN(test_forward_matches_blas);
    RUN(test_gradient_finite_differences);
    RUN(test_adam_fits_a_function);
    RUN(test_table_names);
    unlink(tmp_path);
    return harness_report();
}
