/* unit_contact_sheet.c — the contact sheet (io/contact_sheet.h): its layout from the
 * documented formula, its pixels against the PNG encoder's own conversion (encode_srgb8)
 * and a box filter worked out here, its text (present in the label areas, never outside
 * its cell), placeholders, hostile sizes and strings, every refusal with its message, and
 * the PNG it encodes decoded back. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <zlib.h>

#include "contact_sheet.h"
#include "encode.h"
#include "harness.h"

/* The decoder, compiled static from the system header so the test needs no extra link. */
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_STATIC
#define STBI_ONLY_PNG
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#include <stb/stb_image.h>
#pragma GCC diagnostic pop

static const uint8_t sheet_rgb[3] = {CONTACT_SHEET_SHEET_RGB};
static const uint8_t cell_rgb[3] = {CONTACT_SHEET_CELL_RGB};
static const uint8_t text_rgb[3] = {CONTACT_SHEET_TEXT_RGB};
static const uint8_t placeholder_rgb[3] = {CONTACT_SHEET_PLACEHOLDER_RGB};
static const uint8_t note_rgb[3] = {CONTACT_SHEET_NOTE_RGB};

/* ---------------------------------------------------------------------------------------
 * Helpers.
 * ------------------------------------------------------------------------------------- */

/* w x h pixels all of one linear colour. */
static ns_image flat_image(uint32_t w, uint32_t h, float r, float g, float b)
{
    ns_image img = {w, h, malloc(sizeof(float) * 3 * (size_t)w * h)};
    for (size_t i = 0; i < (size_t)w * h; i++) {
        img.rgb[3 * i] = r;
        img.rgb[3 * i + 1] = g;
        img.rgb[3 * i + 2] = b;
    }
    return img;
}

/* A sheet composed into a buffer of its own. */
typedef struct composed {
    contact_sheet_layout layout;
    uint8_t *rgb;
    int rc;
} composed;

static composed compose(const contact_sheet_desc *desc)
{
    composed c = {0};
    ns_error err = {0};
    c.rc = contact_sheet_layout_of(desc, &c.layout, &err);
    CHECK_INT(c.rc, 0);
    if (c.rc) {
        fprintf(stderr, "  layout: %s\n", err.message);
        return c;
    }
    size_t size = (size_t)c.layout.width * c.layout.height * 3;
    c.rgb = malloc(size);
    c.rc = contact_sheet_compose(desc, &c.layout, c.rgb, size, &err);
    CHECK_INT(c.rc, 0);
    if (c.rc)
        fprintf(stderr, "  compose: %s\n", err.message);
    return c;
}

static const uint8_t *pixel(const composed *c, uint32_t x, uint32_t y)
{
    return c->rgb + 3 * ((size_t)y * c->layout.width + x);
}

static int is(const uint8_t *p, const uint8_t rgb[3])
{
    return p[0] == rgb[0] && p[1] == rgb[1] && p[2] == rgb[2];
}

/* Pixels of colour rgb in [x0, x1) x [y0, y1). */
static size_t count_colour(const composed *c, uint32_t x0, uint32_t y0, uint32_t x1, uint32_t y1,
                           const uint8_t rgb[3])
{
    size_t n = 0;
    for (uint32_t y = y0; y < y1; y++)
        for (uint32_t x = x0; x < x1; x++)
            n += is(pixel(c, x, y), rgb);
    return n;
}

/* Index of the cell whose rectangle holds (x, y), or -1 for the gaps. */
static long cell_at(const contact_sheet_desc *desc, const contact_sheet_layout *l, uint32_t x,
                    uint32_t y)
{
    for (size_t i = 0; i < desc->cell_count; i++) {
        contact_sheet_place p = contact_sheet_place_of(desc, l, i);
        if (x >= p.cell_x && x < p.cell_x + l->cell_width && y >= p.cell_y &&
            y < p.cell_y + l->cell_height)
            return (long)i;
    }
    return -1;
}

static uint32_t get_be32(const unsigned char *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

/* Checks the chunk list (signature, CRCs, IHDR first, IEND last); returns the IHDR size and
 * the value of tEXt `key` ("" when absent). */
static int png_walk(const encode_buffer *png, uint32_t *w, uint32_t *h, const char *key,
                    char *value, size_t cap)
{
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    value[0] = 0;
    if (png->size < 8 + 25 || memcmp(png->data, sig, 8) != 0 ||
        memcmp(png->data + 12, "IHDR", 4) != 0)
        return 0;
    *w = get_be32(png->data + 16);
    *h = get_be32(png->data + 20);
    size_t at = 8;
    while (at + 12 <= png->size) {
        uint32_t len = get_be32(png->data + at);
        const unsigned char *type = png->data + at + 4, *data = type + 4;
        if (at + 12 + len > png->size || (uint32_t)crc32(0L, type, 4 + len) != get_be32(data + len))
            return 0;
        size_t klen = strlen(key);
        if (!memcmp(type, "tEXt", 4) && len > klen && !memcmp(data, key, klen) && !data[klen]) {
            size_t vlen = len - klen - 1 < cap - 1 ? len - klen - 1 : cap - 1;
            memcpy(value, data + klen + 1, vlen);
            value[vlen] = 0;
        }
        if (!memcmp(type, "IEND", 4))
            return at + 12 + len == png->size;
        at += 12 + len;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------
 * Layout.
 * ------------------------------------------------------------------------------------- */
static void test_layout_follows_the_formula(void)
{
    ns_image img = flat_image(40, 30, 0.2f, 0.3f, 0.4f);
    const char *lines[] = {"g=0.5", "12 ms"};
    contact_sheet_cell cells[5];
    for (int i = 0; i < 5; i++)
        cells[i] = (contact_sheet_cell){.image = &img, .lines = lines, .line_count = 2};
    contact_sheet_layout l;
    ns_error err = {0};
    CHECK_INT(contact_sheet_layout_of(
                  &(contact_sheet_desc){.cells = cells, .cell_count = 5, .columns = 3}, &l, &err),
              0);
    /* cell 64 (the minimum) x (30 + 4 + 2 * 12 + 4); 3 columns, 2 rows, gaps of 8. */
    CHECK_INT(l.columns, 3);
    CHECK_INT(l.rows, 2);
    CHECK_INT(l.cell_width, CONTACT_SHEET_MIN_CELL_WIDTH);
    CHECK_INT(l.image_height, 30);
    CHECK_INT(l.label_height, 2 * CONTACT_SHEET_LABEL_PAD + 2 * CONTACT_SHEET_LINE_HEIGHT);
    CHECK_INT(l.cell_height, 30 + 32);
    CHECK_INT(l.width, 8 + 3 * (64 + 8));
    CHECK_INT(l.height, 8 + 2 * (62 + 8));
    /* Cell 4: column 1, row 1; its 40-wide image centred in the 64-wide cell. */
    contact_sheet_place p = contact_sheet_place_of(
        &(contact_sheet_desc){.cells = cells, .cell_count = 5, .columns = 3}, &l, 4);
    CHECK_INT(p.cell_x, 8 + 72);
    CHECK_INT(p.cell_y, 8 + 70);
    CHECK_INT(p.label_y, 8 + 70 + 30);
    CHECK_INT(p.image_x, 8 + 72 + 12);
    CHECK_INT(p.image_y, 8 + 70);
    CHECK_INT(p.factor, 1);

    /* More columns than cells: one row of them all. */
    CHECK_INT(contact_sheet_layout_of(
                  &(contact_sheet_desc){.cells = cells, .cell_count = 5, .columns = 99}, &l, &err),
              0);
    CHECK_INT(l.columns, 5);
    CHECK_INT(l.rows, 1);

    /* No lines anywhere: no label area. */
    contact_sheet_cell bare[1] = {{.image = &img}};
    CHECK_INT(
        contact_sheet_layout_of(&(contact_sheet_desc){.cells = bare, .cell_count = 1}, &l, &err),
        0);
    CHECK_INT(l.label_height, 0);
    CHECK_INT(l.width, 8 + 64 + 8);
    CHECK_INT(l.height, 8 + 30 + 8);
    ns_image_free(&img);
}

static void test_default_columns_make_it_about_square(void)
{
    ns_image square = flat_image(100, 100, 0.5f, 0.5f, 0.5f);
    ns_image wide = flat_image(256, 24, 0.5f, 0.5f, 0.5f);
    contact_sheet_cell cells[30];
    contact_sheet_layout l;
    ns_error err = {0};
    const struct {
        const ns_image *img;
        size_t count;
        uint32_t columns;
    } cases[] = {{&square, 1, 1},
                 {&square, 3, 2},
                 {&square, 4, 2},
                 {&square, 9, 3},
                 /* 3 x 4 and 4 x 3 are as square: the fewer columns */
                 {&square, 10, 3},
                 {&square, 16, 4},
                 {&wide, 6, 1},
                 {&wide, 30, 2}};
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        for (size_t i = 0; i < cases[k].count; i++)
            cells[i] = (contact_sheet_cell){.image = cases[k].img};
        CHECK_INT(
            contact_sheet_layout_of(
                &(contact_sheet_desc){.cells = cells, .cell_count = cases[k].count}, &l, &err),
            0);
        CHECK_INT(l.columns, cases[k].columns);
        CHECK(l.columns * l.rows >= cases[k].count);
        CHECK((l.rows - 1) * l.columns < cases[k].count); /* no empty last row */
    }
    ns_image_free(&square);
    ns_image_free(&wide);
}

/* ---------------------------------------------------------------------------------------
 * Pixels.
 * ------------------------------------------------------------------------------------- */
static void test_image_pixels_are_the_encoders(void)
{
    /* A gradient past 1 (clamped), with NaN and negative values; exposure 1.5 stops. */
    ns_image img = flat_image(37, 21, 0, 0, 0);
    for (uint32_t y = 0; y < img.height; y++)
        for (uint32_t x = 0; x < img.width; x++) {
            float *px = img.rgb + 3 * ((size_t)y * img.width + x);
            px[0] = 1.2f * (float)x / 36.0f;
            px[1] = (float)y / 20.0f * 0.3f;
            px[2] = (x + y) % 7 == 0 ? NAN : (x % 3 == 0 ? -0.5f : 0.002f * (float)x);
        }
    const char *lines[] = {"x"};
    contact_sheet_cell cells[2] = {{.lines = lines, .line_count = 1},
                                   {.image = &img, .lines = lines, .line_count = 1}};
    contact_sheet_desc desc = {.cells = cells, .cell_count = 2, .exposure_stops = 1.5f};
    composed c = compose(&desc);
    if (c.rc)
        return;
    contact_sheet_place p = contact_sheet_place_of(&desc, &c.layout, 1);
    float scale = exp2f(1.5f);
    /* The image's origin pixel, then every pixel. */
    for (int ch = 0; ch < 3; ch++)
        CHECK_INT(pixel(&c, p.image_x, p.image_y)[ch], encode_srgb8(img.rgb[ch], scale));
    size_t wrong = 0;
    for (uint32_t y = 0; y < img.height; y++)
        for (uint32_t x = 0; x < img.width; x++)
            for (int ch = 0; ch < 3; ch++)
                wrong += pixel(&c, p.image_x + x, p.image_y + y)[ch] !=
                         encode_srgb8(img.rgb[3 * ((size_t)y * img.width + x) + ch], scale);
    CHECK_INT(wrong, 0);

    /* The same as what encode_png writes for the image alone. */
    encode_buffer png;
    ns_error err = {0};
    CHECK_INT(encode_png(&img, 1.5f, NULL, 0, &png, &err), 0);
    int w = 0, h = 0, n = 0;
    unsigned char *dec =
        png.data ? stbi_load_from_memory(png.data, (int)png.size, &w, &h, &n, 3) : NULL;
    CHECK(dec != NULL);
    if (dec) {
        size_t differ = 0;
        for (uint32_t y = 0; y < img.height; y++)
            differ += memcmp(pixel(&c, p.image_x, p.image_y + y), dec + (size_t)y * w * 3,
                             (size_t)w * 3) != 0;
        CHECK_INT(differ, 0);
    }
    stbi_image_free(dec);
    encode_buffer_free(&png);
    free(c.rgb);
    ns_image_free(&img);
}

static void test_downscale_averages_boxes(void)
{
    /* 8 x 4 checkerboard of 0 and 1, at most 4 a side: factor 2, 4 x 2 of the mean 0.5. */
    ns_image checker = flat_image(8, 4, 0, 0, 0);
    for (uint32_t i = 0; i < 8 * 4; i++) {
        float v = ((i % 8) + (i / 8)) % 2 ? 1.0f : 0.0f;
        checker.rgb[3 * i] = v;
        checker.rgb[3 * i + 1] = 1.0f - v;
        checker.rgb[3 * i + 2] = 0.25f * v;
    }
    /* 5 x 3 ramp at most 4 a side: factor 2, 3 x 2, the last column and row boxes cut to the
     * pixels there are (1 wide, 1 tall). */
    ns_image ramp = flat_image(5, 3, 0, 0, 0);
    for (uint32_t y = 0; y < 3; y++)
        for (uint32_t x = 0; x < 5; x++)
            for (int ch = 0; ch < 3; ch++)
                ramp.rgb[3 * (y * 5 + x) + ch] = (float)(x + 5 * y) / 20.0f + 0.1f * (float)ch;
    contact_sheet_cell cells[2] = {{.image = &checker}, {.image = &ramp}};
    contact_sheet_desc desc = {.cells = cells, .cell_count = 2, .max_cell_side = 4};
    composed c = compose(&desc);
    if (c.rc)
        return;
    contact_sheet_place p = contact_sheet_place_of(&desc, &c.layout, 0);
    CHECK_INT(p.factor, 2);
    CHECK_INT(p.image_width, 4);
    CHECK_INT(p.image_height, 2);
    CHECK_INT(c.layout.image_height, 2);
    for (uint32_t y = 0; y < 2; y++)
        for (uint32_t x = 0; x < 4; x++) {
            const uint8_t *px = pixel(&c, p.image_x + x, p.image_y + y);
            CHECK_INT(px[0], encode_srgb8(0.5f, 1.0f));
            CHECK_INT(px[1], encode_srgb8(0.5f, 1.0f));
            CHECK_INT(px[2], encode_srgb8(0.125f, 1.0f));
        }
    p = contact_sheet_place_of(&desc, &c.layout, 1);
    CHECK_INT(p.factor, 2);
    CHECK_INT(p.image_width, 3);
    CHECK_INT(p.image_height, 2);
    for (uint32_t oy = 0; oy < 2; oy++)
        for (uint32_t ox = 0; ox < 3; ox++)
            for (int ch = 0; ch < 3; ch++) {
                double sum = 0;
                int n = 0;
                for (uint32_t y = 2 * oy; y < 2 * oy + 2 && y < 3; y++)
                    for (uint32_t x = 2 * ox; x < 2 * ox + 2 && x < 5; x++, n++)
                        sum += ramp.rgb[3 * (y * 5 + x) + ch];
                CHECK_INT(pixel(&c, p.image_x + ox, p.image_y + oy)[ch],
                          encode_srgb8((float)(sum / n), 1.0f));
            }
    /* The corner box is one pixel: its value as it is. */
    CHECK_INT(pixel(&c, p.image_x + 2, p.image_y + 1)[0], encode_srgb8(ramp.rgb[3 * 14], 1.0f));
    free(c.rgb);
    ns_image_free(&checker);
    ns_image_free(&ramp);
}

/* ---------------------------------------------------------------------------------------
 * Text and placeholders.
 * ------------------------------------------------------------------------------------- */
static void test_labels_and_placeholders(void)
{
    /* A colour that is none of the sheet's own. */
    ns_image img = flat_image(48, 32, 0.05f, 0.4f, 0.9f);
    const char *done_lines[] = {"/materials/wax/g=0.5", "812.3 ms"};
    const char *queued_lines[] = {"/materials/wax/g=0.8", "queued"};
    contact_sheet_cell cells[2] = {
        {.image = &img, .lines = done_lines, .line_count = 2},
        {.lines = queued_lines, .line_count = 2, .note = "queued", .width = 48, .height = 32},
    };
    contact_sheet_desc desc = {.cells = cells, .cell_count = 2, .columns = 2, .max_cell_side = 128};
    composed c = compose(&desc);
    if (c.rc)
        return;
    uint8_t image_rgb[3];
    for (int ch = 0; ch < 3; ch++)
        image_rgb[ch] = encode_srgb8(img.rgb[ch], 1.0f);
    for (size_t i = 0; i < 2; i++) {
        contact_sheet_place p = contact_sheet_place_of(&desc, &c.layout, i);
        uint32_t x1 = p.cell_x + c.layout.cell_width, y1 = p.cell_y + c.layout.cell_height;
        /* Text in the label area, none in the image area. */
        CHECK(count_colour(&c, p.cell_x, p.label_y, x1, y1, text_rgb) > 20);
        CHECK_INT(count_colour(&c, p.cell_x, p.cell_y, x1, p.label_y, text_rgb), 0);
        if (i == 0) {
            CHECK_INT(count_colour(&c, p.image_x, p.image_y, p.image_x + p.image_width,
                                   p.image_y + p.image_height, image_rgb),
                      48 * 32);
            CHECK_INT(count_colour(&c, p.cell_x, p.cell_y, x1, y1, placeholder_rgb), 0);
        } else {
            /* The placeholder: its own colour and its note, nothing of any image. */
            CHECK_INT(p.image_width, 48);
            CHECK_INT(p.image_height, 32);
            size_t fill = count_colour(&c, p.image_x, p.image_y, p.image_x + 48, p.image_y + 32,
                                       placeholder_rgb);
            size_t note =
                count_colour(&c, p.image_x, p.image_y, p.image_x + 48, p.image_y + 32, note_rgb);
            CHECK(note > 10);
            CHECK_INT(fill + note, 48 * 32);
            CHECK_INT(count_colour(&c, p.cell_x, p.cell_y, x1, y1, image_rgb), 0);
            CHECK_INT(count_colour(&c, 0, 0, c.layout.width, c.layout.height, note_rgb), note);
        }
    }
    free(c.rgb);
    ns_image_free(&img);
}

/* Long, hostile and empty lines on narrow cells: text pixels only inside the label area of a
 * cell (minus its side padding), the gaps untouched, and a cut line ends in "...". */
static void test_text_stays_in_its_cell(void)
{
    char longest[2048];
    memset(longest, 'W', sizeof longest - 1);
    longest[sizeof longest - 1] = 0;
    const char *lines[] = {longest, "", NULL, "caf\xc3\xa9 \t\x7f\x01 ~", longest + 2000};
    ns_image tiny = flat_image(1, 1, 0.3f, 0.3f, 0.3f);
    ns_image wide = flat_image(4000, 1, 0.3f, 0.3f, 0.3f);
    ns_image tall = flat_image(1, 700, 0.3f, 0.3f, 0.3f);
    contact_sheet_cell cells[7] = {
        {.image = &tiny, .lines = lines, .line_count = 5},
        {.image = &wide, .lines = lines, .line_count = 5},
        {.image = &tall, .lines = lines, .line_count = 1},
        {.lines = lines, .line_count = 5, .note = longest},
        {.image = &tiny},
        {.lines = NULL, .line_count = 0},
        {.image = &tiny, .lines = lines + 1, .line_count = 2},
    };
    contact_sheet_desc desc = {.cells = cells, .cell_count = 7, .columns = 3, .max_cell_side = 50};
    composed c = compose(&desc);
    if (c.rc)
        return;
    CHECK_INT(c.layout.cell_width, CONTACT_SHEET_MIN_CELL_WIDTH);
    CHECK_INT(c.layout.image_height, 50);
    size_t stray = 0, gaps_wrong = 0, text = 0;
    for (uint32_t y = 0; y < c.layout.height; y++)
        for (uint32_t x = 0; x < c.layout.width; x++) {
            const uint8_t *px = pixel(&c, x, y);
            long i = cell_at(&desc, &c.layout, x, y);
            if (i < 0) {
                gaps_wrong += !is(px, sheet_rgb);
                continue;
            }
            if (!is(px, text_rgb))
                continue;
            text++;
            contact_sheet_place p = contact_sheet_place_of(&desc, &c.layout, (size_t)i);
            stray += x < p.cell_x + CONTACT_SHEET_LABEL_PAD ||
                     x >= p.cell_x + c.layout.cell_width - CONTACT_SHEET_LABEL_PAD || y < p.label_y;
        }
    CHECK(text > 100);
    CHECK_INT(stray, 0);
    CHECK_INT(gaps_wrong, 0);

    /* Cell 0's first line is cut: its last text column lies in the final "..." (dots are one
     * pixel tall, on the glyph baseline row), and it reaches close to the padding. */
    contact_sheet_place p = contact_sheet_place_of(&desc, &c.layout, 0);
    uint32_t line_top = p.label_y + CONTACT_SHEET_LABEL_PAD;
    uint32_t last = 0;
    for (uint32_t x = p.cell_x; x < p.cell_x + c.layout.cell_width; x++)
        if (count_colour(&c, x, line_top, x + 1, line_top + CONTACT_SHEET_LINE_HEIGHT, text_rgb))
            last = x;
    CHECK(last + 12 >= p.cell_x + c.layout.cell_width - CONTACT_SHEET_LABEL_PAD);
    CHECK_INT(
        count_colour(&c, last, line_top, last + 1, line_top + CONTACT_SHEET_LINE_HEIGHT, text_rgb),
        1);
    /* Empty and NULL lines draw nothing: cell 6's label area is blank. */
    p = contact_sheet_place_of(&desc, &c.layout, 6);
    CHECK_INT(count_colour(&c, p.cell_x, p.label_y, p.cell_x + c.layout.cell_width,
                           p.cell_y + c.layout.cell_height, text_rgb),
              0);
    CHECK_INT(count_colour(&c, p.cell_x, p.label_y, p.cell_x + c.layout.cell_width,
                           p.cell_y + c.layout.cell_height, cell_rgb),
              (size_t)c.layout.cell_width * c.layout.label_height);
    /* The very wide image: 4000 x 1 by factor 80 to 50 x 1. */
    p = contact_sheet_place_of(&desc, &c.layout, 1);
    CHECK_INT(p.factor, 80);
    CHECK_INT(p.image_width, 50);
    CHECK_INT(p.image_height, 1);
    free(c.rgb);
    ns_image_free(&tiny);
    ns_image_free(&wide);
    ns_image_free(&tall);
}

/* ---------------------------------------------------------------------------------------
 * The PNG.
 * ------------------------------------------------------------------------------------- */
static void test_png_decodes_to_the_composed_sheet(void)
{
    ns_image img = flat_image(33, 17, 0.7f, 0.2f, 0.1f);
    const char *lines[] = {"/materials/wax/albedo=[0.9,0.9,0.9]", "1.25 s  reused bvh"};
    contact_sheet_cell cells[3] = {
        {.image = &img, .lines = lines, .line_count = 2},
        {.image = &img, .lines = lines, .line_count = 1},
        {.lines = lines, .line_count = 2, .note = "running"},
    };
    encode_text extra[] = {{"nscatter:sweep", "{\"variants\": 3}"}};
    contact_sheet_desc desc = {
        .cells = cells, .cell_count = 3, .exposure_stops = -0.5f, .texts = extra, .text_count = 1};
    composed c = compose(&desc);
    encode_buffer png;
    ns_error err = {0};
    CHECK_INT(contact_sheet_png(&desc, &png, &err), 0);
    if (c.rc || !png.data)
        return;
    uint32_t w = 0, h = 0;
    char value[128];
    CHECK(png_walk(&png, &w, &h, "Software", value, sizeof value));
    CHECK_INT(w, c.layout.width);
    CHECK_INT(h, c.layout.height);
    CHECK(strcmp(value, "nscatter " NS_VERSION) == 0);
    CHECK(png_walk(&png, &w, &h, "nscatter:sweep", value, sizeof value));
    CHECK(strcmp(value, extra[0].value) == 0);
    int dw = 0, dh = 0, dn = 0;
    unsigned char *dec = stbi_load_from_memory(png.data, (int)png.size, &dw, &dh, &dn, 3);
    CHECK(dec != NULL);
    CHECK_INT(dw, c.layout.width);
    CHECK_INT(dh, c.layout.height);
    CHECK_INT(dn, 3);
    if (dec)
        CHECK(memcmp(dec, c.rgb, (size_t)dw * dh * 3) == 0);
    stbi_image_free(dec);
    encode_buffer_free(&png);
    free(c.rgb);
    ns_image_free(&img);
}

/* ---------------------------------------------------------------------------------------
 * Refusals.
 * ------------------------------------------------------------------------------------- */
static void expect_refused(const contact_sheet_desc *desc, int status, const char *message)
{
    encode_buffer png = {(unsigned char *)"x", 1};
    ns_error err = {0};
    CHECK_INT(contact_sheet_png(desc, &png, &err), status);
    CHECK_INT(err.status, status);
    CHECK_STR_CONTAINS(err.message, message);
    CHECK(png.data == NULL && png.size == 0);
    contact_sheet_layout l;
    err = (ns_error){0};
    CHECK_INT(contact_sheet_layout_of(desc, &l, &err), status);
    CHECK_STR_CONTAINS(err.message, message);
}

static void test_refusals(void)
{
    static contact_sheet_cell many[CONTACT_SHEET_MAX_CELLS + 1];
    ns_image img = flat_image(2, 2, 0.5f, 0.5f, 0.5f);
    for (size_t i = 0; i <= CONTACT_SHEET_MAX_CELLS; i++)
        many[i] = (contact_sheet_cell){.image = &img};

    expect_refused(&(contact_sheet_desc){.cells = many, .cell_count = 0}, NS_ERR_INVALID_ARGUMENT,
                   "contact sheet: no cells");
    expect_refused(&(contact_sheet_desc){.cells = NULL, .cell_count = 3}, NS_ERR_INVALID_ARGUMENT,
                   "no cells");
    expect_refused(NULL, NS_ERR_INVALID_ARGUMENT, "no cells");
    expect_refused(&(contact_sheet_desc){.cells = many, .cell_count = CONTACT_SHEET_MAX_CELLS + 1},
                   NS_ERR_LIMIT, "1025 cells, at most 1024");
    /* 1024 cells is allowed. */
    contact_sheet_layout l;
    ns_error err = {0};
    CHECK_INT(
        contact_sheet_layout_of(
            &(contact_sheet_desc){.cells = many, .cell_count = CONTACT_SHEET_MAX_CELLS}, &l, &err),
        0);

    /* Over a side: three 16384-wide placeholders in a row. */
    contact_sheet_cell wide[3];
    for (int i = 0; i < 3; i++)
        wide[i] = (contact_sheet_cell){.width = 16384, .height = 1};
    expect_refused(
        &(contact_sheet_desc){.cells = wide, .cell_count = 3, .columns = 3, .max_cell_side = 16384},
        NS_ERR_LIMIT, "over the limit of 16384 a side");
    /* A side within the limit but too many pixels: 1024 cells of 300 x 300, about square. */
    for (size_t i = 0; i < CONTACT_SHEET_MAX_CELLS; i++)
        many[i] = (contact_sheet_cell){.width = 300, .height = 300};
    expect_refused(&(contact_sheet_desc){.cells = many,
                                         .cell_count = CONTACT_SHEET_MAX_CELLS,
                                         .max_cell_side = 300},
                   NS_ERR_LIMIT, "pixels, over the limit of 67108864");

    contact_sheet_cell bad[2] = {{.image = &img}, {.image = &(ns_image){0, 5, img.rgb}}};
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2}, NS_ERR_INVALID_ARGUMENT,
                   "cell 1: image without pixels (0x5)");
    bad[1] = (contact_sheet_cell){.image = &(ns_image){4, 4, NULL}};
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2}, NS_ERR_INVALID_ARGUMENT,
                   "cell 1: image without pixels");
    bad[1] = (contact_sheet_cell){.line_count = 2};
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2}, NS_ERR_INVALID_ARGUMENT,
                   "cell 1 counts 2 lines but gives none");
    const char *lines[CONTACT_SHEET_MAX_LINES + 1] = {0};
    bad[1] = (contact_sheet_cell){.lines = lines, .line_count = CONTACT_SHEET_MAX_LINES + 1};
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2}, NS_ERR_LIMIT,
                   "cell 1 has 65 lines, at most 64");
    bad[1] = (contact_sheet_cell){.image = &img};
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2, .exposure_stops = NAN},
                   NS_ERR_INVALID_ARGUMENT, "exposure");
    expect_refused(&(contact_sheet_desc){.cells = bad, .cell_count = 2, .exposure_stops = 65},
                   NS_ERR_INVALID_ARGUMENT, "exposure");

    /* compose: a buffer too small, or a layout of other cells. */
    contact_sheet_desc ok = {.cells = bad, .cell_count = 2};
    CHECK_INT(contact_sheet_layout_of(&ok, &l, &err), 0);
    uint8_t *rgb = malloc((size_t)l.width * l.height * 3);
    CHECK_INT(contact_sheet_compose(&ok, &l, rgb, (size_t)l.width * l.height * 3 - 1, &err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "needs");
    contact_sheet_layout other = l;
    other.columns = 2;
    CHECK_INT(contact_sheet_compose(&ok, &other, rgb, (size_t)l.width * l.height * 3, &err),
              NS_ERR_INVALID_ARGUMENT);
    CHECK_STR_CONTAINS(err.message, "not the layout");
    free(rgb);

    /* The 8-bit PNG writer's own limits. */
    uint8_t px[3] = {1, 2, 3};
    encode_buffer png;
    CHECK_INT(encode_png_rgb8(px, 0, 1, NULL, 0, &png, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(encode_png_rgb8(NULL, 1, 1, NULL, 0, &png, &err), NS_ERR_INVALID_ARGUMENT);
    CHECK_INT(encode_png_rgb8(px, ENCODE_RGB8_MAX_SIDE + 1, 1, NULL, 0, &png, &err), NS_ERR_LIMIT);
    CHECK_INT(encode_png_rgb8(px, 8193, 8193, NULL, 0, &png, &err), NS_ERR_LIMIT);
    CHECK(png.data == NULL);
    ns_image_free(&img);
}

int main(void)
{
    RUN(test_layout_follows_the_formula);
    RUN(test_default_columns_make_it_about_square);
    RUN(test_image_pixels_are_the_encoders);
    RUN(test_downscale_averages_boxes);
    RUN(test_labels_and_placeholders);
    RUN(test_text_stays_in_its_cell);
    RUN(test_png_decodes_to_the_composed_sheet);
    RUN(test_refusals);
    return harness_report();
}
