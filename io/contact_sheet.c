/* contact_sheet.c — a grid of labelled images as one 8-bit sRGB picture and its PNG. */
#include "contact_sheet.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* stb_easy_font builds each glyph from axis-aligned quads; we rasterise those ourselves.
 * All its functions are static; the ones we do not call are reported unused. */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wshadow"
#include <stb/stb_easy_font.h>
#pragma GCC diagnostic pop

typedef struct sheet_rgb {
    uint8_t r, g, b;
} sheet_rgb;

static const sheet_rgb sheet_colour = {CONTACT_SHEET_SHEET_RGB};
static const sheet_rgb cell_colour = {CONTACT_SHEET_CELL_RGB};
static const sheet_rgb text_colour = {CONTACT_SHEET_TEXT_RGB};
static const sheet_rgb placeholder_colour = {CONTACT_SHEET_PLACEHOLDER_RGB};
static const sheet_rgb note_colour = {CONTACT_SHEET_NOTE_RGB};

/* A rectangle [x0, x1) x [y0, y1) on the sheet. */
typedef struct sheet_rect {
    int64_t x0, y0, x1, y1;
} sheet_rect;

/* ---------------------------------------------------------------------------------------
 * Layout.
 * ------------------------------------------------------------------------------------- */

/* The smallest integer factor k with ceil(w / k), ceil(h / k) <= max_side, and those
 * sizes. */
static uint32_t sheet_scaled(uint32_t w, uint32_t h, uint32_t max_side, uint32_t *sw, uint32_t *sh)
{
    uint32_t longest = w > h ? w : h;
    uint32_t k =
        longest <= max_side ? 1 : (uint32_t)(((uint64_t)longest + max_side - 1) / max_side);
    *sw = (uint32_t)(((uint64_t)w + k - 1) / k);
    *sh = (uint32_t)(((uint64_t)h + k - 1) / k);
    return k;
}

static uint64_t sheet_extent(uint64_t count, uint64_t cell)
{
    return CONTACT_SHEET_GAP + count * (cell + CONTACT_SHEET_GAP);
}

int contact_sheet_layout_of(const contact_sheet_desc *desc, contact_sheet_layout *out,
                            ns_error *err)
{
    memset(out, 0, sizeof *out);
    if (!desc || desc->cell_count == 0 || !desc->cells)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "contact sheet: no cells");
    if (desc->cell_count > CONTACT_SHEET_MAX_CELLS)
        return ns_fail(err, NS_ERR_LIMIT, "contact sheet: %zu cells, at most %u", desc->cell_count,
                       CONTACT_SHEET_MAX_CELLS);
    float scale;
    int rc = encode_exposure_scale(desc->exposure_stops, &scale, err);
    if (rc)
        return rc;
    if (desc->text_count >= ENCODE_MAX_TEXTS || (desc->text_count && !desc->texts))
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "contact sheet: %zu metadata texts, at most %d and given", desc->text_count,
                       ENCODE_MAX_TEXTS - 1);
    uint32_t max_side = desc->max_cell_side ? desc->max_cell_side : CONTACT_SHEET_DEFAULT_CELL_SIDE;

    uint64_t widest = 0, tallest = 0, most_lines = 0;
    for (size_t i = 0; i < desc->cell_count; i++) {
        const contact_sheet_cell *c = &desc->cells[i];
        if (c->line_count > CONTACT_SHEET_MAX_LINES)
            return ns_fail(err, NS_ERR_LIMIT, "contact sheet: cell %zu has %zu lines, at most %u",
                           i, c->line_count, CONTACT_SHEET_MAX_LINES);
        if (c->line_count && !c->lines)
            return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                           "contact sheet: cell %zu counts %zu lines but gives none", i,
                           c->line_count);
        most_lines = c->line_count > most_lines ? c->line_count : most_lines;
        uint32_t w = 0, h = 0;
        if (c->image) {
            if (!c->image->rgb || c->image->width == 0 || c->image->height == 0)
                return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                               "contact sheet: cell %zu: image without pixels (%ux%u)", i,
                               c->image->width, c->image->height);
            w = c->image->width;
            h = c->image->height;
        } else if (c->width && c->height) {
            w = c->width;
            h = c->height;
        }
        if (w && h) {
            uint32_t sw, sh;
            sheet_scaled(w, h, max_side, &sw, &sh);
            widest = sw > widest ? sw : widest;
            tallest = sh > tallest ? sh : tallest;
        }
    }
    if (widest == 0) /* nothing but placeholders of unknown size */
        widest = tallest = max_side;

    uint64_t cell_w = widest > CONTACT_SHEET_MIN_CELL_WIDTH ? widest : CONTACT_SHEET_MIN_CELL_WIDTH;
    uint64_t label_h =
        most_lines ? 2 * CONTACT_SHEET_LABEL_PAD + CONTACT_SHEET_LINE_HEIGHT * most_lines : 0;
    uint64_t cell_h = tallest + label_h;
    uint64_t n = desc->cell_count, columns = desc->columns;
    if (columns > n)
        columns = n;
    if (columns == 0) {
        /* The column count whose sheet is closest to square; the fewest columns on a tie. */
        double best = INFINITY;
        for (uint64_t c = 1; c <= n; c++) {
            double w = (double)sheet_extent(c, cell_w);
            double h = (double)sheet_extent((n + c - 1) / c, cell_h);
            double ratio = w > h ? w / h : h / w;
            if (ratio < best) {
                best = ratio;
                columns = c;
            }
        }
    }
    uint64_t rows = (n + columns - 1) / columns;
    uint64_t width = sheet_extent(columns, cell_w), height = sheet_extent(rows, cell_h);
    if (width > CONTACT_SHEET_MAX_SIDE || height > CONTACT_SHEET_MAX_SIDE)
        return ns_fail(err, NS_ERR_LIMIT,
                       "contact sheet: %llux%llu pixels, over the limit of %u a side "
                       "(%llu columns of %llux%llu cells)",
                       (unsigned long long)width, (unsigned long long)height,
                       CONTACT_SHEET_MAX_SIDE, (unsigned long long)columns,
                       (unsigned long long)cell_w, (unsigned long long)cell_h);
    if (width * height > CONTACT_SHEET_MAX_PIXELS)
        return ns_fail(err, NS_ERR_LIMIT,
                       "contact sheet: %llux%llu is %llu pixels, over the limit of %u",
                       (unsigned long long)width, (unsigned long long)height,
                       (unsigned long long)(width * height), CONTACT_SHEET_MAX_PIXELS);
    *out = (contact_sheet_layout){
        .width = (uint32_t)width,
        .height = (uint32_t)height,
        .columns = (uint32_t)columns,
        .rows = (uint32_t)rows,
        .cell_width = (uint32_t)cell_w,
        .cell_height = (uint32_t)cell_h,
        .image_height = (uint32_t)tallest,
        .label_height = (uint32_t)label_h,
        .max_cell_side = max_side,
    };
    return 0;
}

contact_sheet_place contact_sheet_place_of(const contact_sheet_desc *desc,
                                           const contact_sheet_layout *layout, size_t index)
{
    const contact_sheet_cell *c = &desc->cells[index];
    contact_sheet_place p = {0};
    uint32_t column = (uint32_t)(index % layout->columns),
             row = (uint32_t)(index / layout->columns);
    p.cell_x = CONTACT_SHEET_GAP + column * (layout->cell_width + CONTACT_SHEET_GAP);
    p.cell_y = CONTACT_SHEET_GAP + row * (layout->cell_height + CONTACT_SHEET_GAP);
    p.label_y = p.cell_y + layout->image_height;
    p.factor = 1;
    if (c->image)
        p.factor = sheet_scaled(c->image->width, c->image->height, layout->max_cell_side,
                                &p.image_width, &p.image_height);
    else if (c->width && c->height)
        p.factor = sheet_scaled(c->width, c->height, layout->max_cell_side, &p.image_width,
                                &p.image_height);
    else {
        p.image_width = layout->cell_width;
        p.image_height = layout->image_height;
    }
    p.image_x = p.cell_x + (layout->cell_width - p.image_width) / 2;
    p.image_y = p.cell_y + (layout->image_height - p.image_height) / 2;
    return p;
}

/* ---------------------------------------------------------------------------------------
 * Drawing.
 * ------------------------------------------------------------------------------------- */
typedef struct sheet_canvas {
    uint8_t *rgb;
    uint32_t width, height;
} sheet_canvas;

/* Fills r clipped to `clip` (and to the canvas). */
static void sheet_fill(const sheet_canvas *cv, sheet_rect r, sheet_rect clip, sheet_rgb colour)
{
    if (r.x0 < clip.x0)
        r.x0 = clip.x0;
    if (r.y0 < clip.y0)
        r.y0 = clip.y0;
    if (r.x1 > clip.x1)
        r.x1 = clip.x1;
    if (r.y1 > clip.y1)
        r.y1 = clip.y1;
    if (r.x0 < 0)
        r.x0 = 0;
    if (r.y0 < 0)
        r.y0 = 0;
    if (r.x1 > cv->width)
        r.x1 = cv->width;
    if (r.y1 > cv->height)
        r.y1 = cv->height;
    for (int64_t y = r.y0; y < r.y1; y++)
        for (int64_t x = r.x0; x < r.x1; x++) {
            uint8_t *p = cv->rgb + 3 * ((size_t)y * cv->width + (size_t)x);
            p[0] = colour.r;
            p[1] = colour.g;
            p[2] = colour.b;
        }
}

/* The character stb_easy_font draws for byte *s, and how many bytes it stands for: printable
 * ASCII as it is; anything else as '?', a whole UTF-8 sequence as one (stb_easy_font indexes
 * its tables with c - 32, so nothing outside 32..126 may reach it). */
static char sheet_glyph(const char *s, size_t *bytes)
{
    unsigned char c = (unsigned char)s[0];
    *bytes = 1;
    if (c >= 32 && c <= 126)
        return (char)c;
    if (c >= 0xc0)
        while ((((unsigned char)s[*bytes]) & 0xc0) == 0x80)
            (*bytes)++;
    return '?';
}

static int sheet_advance(char c)
{
    return stb_easy_font_charinfo[c - 32].advance & 15;
}

/* Draws one glyph with its top left corner at (x, y), clipped to `clip`. */
static void sheet_draw_glyph(const sheet_canvas *cv, int64_t x, int64_t y, char c, sheet_rect clip,
                             sheet_rgb colour)
{
    /* 64 bytes per quad (4 vertices); stb_easy_font 1.1's glyphs have at most 11 quads. */
    char vertices[64 * 64];
    char text[2] = {c, 0};
    int quads = stb_easy_font_print(0.0f, 0.0f, text, NULL, vertices, (int)sizeof vertices);
    for (int q = 0; q < quads; q++) {
        /* Vertex 0 is the quad's top left corner, vertex 2 its bottom right. */
        float v0[2], v2[2];
        memcpy(v0, vertices + 64 * q, sizeof v0);
        memcpy(v2, vertices + 64 * q + 32, sizeof v2);
        sheet_rect r = {x + (int64_t)lroundf(v0[0]), y + (int64_t)lroundf(v0[1]),
                        x + (int64_t)lroundf(v2[0]), y + (int64_t)lroundf(v2[1])};
        sheet_fill(cv, r, clip, colour);
    }
}

/* Draws `line` from (x, y) within `clip`: whole when it fits in clip's width, else as many
 * characters as fit followed by "...". */
static void sheet_draw_line(const sheet_canvas *cv, int64_t x, int64_t y, const char *line,
                            sheet_rect clip, sheet_rgb colour)
{
    if (!line)
        return;
    int64_t room = clip.x1 - x, width = 0, ellipsis = 3 * sheet_advance('.');
    /* How many bytes fit whole, and how many fit with the ellipsis after them. */
    size_t at = 0, fits_with_ellipsis = 0;
    int whole = 1;
    while (line[at]) {
        size_t bytes;
        char c = sheet_glyph(line + at, &bytes);
        if (width + sheet_advance(c) > room) {
            whole = 0;
            break;
        }
        width += sheet_advance(c);
        at += bytes;
        if (width + ellipsis <= room)
            fits_with_ellipsis = at;
    }
    size_t end = whole ? at : fits_with_ellipsis;
    for (size_t i = 0; i < end;) {
        size_t bytes;
        char c = sheet_glyph(line + i, &bytes);
        sheet_draw_glyph(cv, x, y, c, clip, colour);
        x += sheet_advance(c);
        i += bytes;
    }
    if (!whole)
        for (int i = 0; i < 3; i++, x += sheet_advance('.'))
            sheet_draw_glyph(cv, x, y, '.', clip, colour);
}

/* The image's pixels, box-filtered by p->factor, converted with the PNG encoder's
 * encode_srgb8. */
static void sheet_draw_image(const sheet_canvas *cv, const ns_image *img,
                             const contact_sheet_place *p, float scale)
{
    uint32_t k = p->factor;
    for (uint32_t oy = 0; oy < p->image_height; oy++) {
        uint32_t y0 = oy * k, y1 = y0 + k < img->height ? y0 + k : img->height;
        for (uint32_t ox = 0; ox < p->image_width; ox++) {
            uint32_t x0 = ox * k, x1 = x0 + k < img->width ? x0 + k : img->width;
            uint8_t *dst = cv->rgb + 3 * ((size_t)(p->image_y + oy) * cv->width + p->image_x + ox);
            if (k == 1) {
                const float *src = img->rgb + 3 * ((size_t)y0 * img->width + x0);
                for (int ch = 0; ch < 3; ch++)
                    dst[ch] = encode_srgb8(src[ch], scale);
                continue;
            }
            double sum[3] = {0, 0, 0};
            for (uint32_t y = y0; y < y1; y++)
                for (uint32_t x = x0; x < x1; x++) {
                    const float *src = img->rgb + 3 * ((size_t)y * img->width + x);
                    for (int ch = 0; ch < 3; ch++)
                        sum[ch] += src[ch];
                }
            double count = (double)(y1 - y0) * (double)(x1 - x0);
            for (int ch = 0; ch < 3; ch++)
                dst[ch] = encode_srgb8((float)(sum[ch] / count), scale);
        }
    }
}

static void sheet_draw_cell(const sheet_canvas *cv, const contact_sheet_desc *desc,
                            const contact_sheet_layout *layout, size_t index, float scale)
{
    const contact_sheet_cell *c = &desc->cells[index];
    contact_sheet_place p = contact_sheet_place_of(desc, layout, index);
    sheet_rect cell = {p.cell_x, p.cell_y, (int64_t)p.cell_x + layout->cell_width,
                       (int64_t)p.cell_y + layout->cell_height};
    sheet_fill(cv, cell, cell, cell_colour);
    sheet_rect picture = {p.image_x, p.image_y, (int64_t)p.image_x + p.image_width,
                          (int64_t)p.image_y + p.image_height};
    if (c->image) {
        sheet_draw_image(cv, c->image, &p, scale);
    } else {
        sheet_fill(cv, picture, picture, placeholder_colour);
        if (c->note) {
            /* Centred in the placeholder when it fits, else from its left edge with "...". */
            int64_t width = 0;
            for (size_t at = 0, bytes; c->note[at]; at += bytes)
                width += sheet_advance(sheet_glyph(c->note + at, &bytes));
            int64_t room = picture.x1 - picture.x0;
            int64_t x = picture.x0 + (width < room ? (room - width) / 2 : 0);
            int64_t y = picture.y0 + ((picture.y1 - picture.y0) - 9) / 2;
            sheet_draw_line(cv, x, y, c->note, picture, note_colour);
        }
    }
    sheet_rect label = {(int64_t)p.cell_x + CONTACT_SHEET_LABEL_PAD, p.label_y,
                        cell.x1 - CONTACT_SHEET_LABEL_PAD, cell.y1};
    for (size_t i = 0; i < c->line_count; i++)
        sheet_draw_line(cv, label.x0,
                        label.y0 + CONTACT_SHEET_LABEL_PAD + CONTACT_SHEET_LINE_HEIGHT * (int64_t)i,
                        c->lines[i], label, text_colour);
}

int contact_sheet_compose(const contact_sheet_desc *desc, const contact_sheet_layout *layout,
                          uint8_t *rgb, size_t rgb_size, ns_error *err)
{
    contact_sheet_layout check;
    int rc = contact_sheet_layout_of(desc, &check, err);
    if (rc)
        return rc;
    if (memcmp(&check, layout, sizeof check) != 0)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "contact sheet: the layout given is not the layout of these cells");
    size_t need = (size_t)layout->width * layout->height * 3;
    if (!rgb || rgb_size < need)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "contact sheet: %zu bytes for a %ux%u sheet that needs %zu", rgb_size,
                       layout->width, layout->height, need);
    float scale = 1.0f;
    encode_exposure_scale(desc->exposure_stops, &scale, NULL); /* checked by the layout */
    sheet_canvas cv = {rgb, layout->width, layout->height};
    sheet_rect all = {0, 0, layout->width, layout->height};
    sheet_fill(&cv, all, all, sheet_colour);
    for (size_t i = 0; i < desc->cell_count; i++)
        sheet_draw_cell(&cv, desc, layout, i, scale);
    return 0;
}

int contact_sheet_png(const contact_sheet_desc *desc, encode_buffer *out, ns_error *err)
{
    out->data = NULL;
    out->size = 0;
    contact_sheet_layout layout;
    int rc = contact_sheet_layout_of(desc, &layout, err);
    if (rc)
        return rc;
    size_t size = (size_t)layout.width * layout.height * 3;
    uint8_t *rgb = malloc(size);
    if (!rgb)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY,
                       "contact sheet: out of memory for %ux%u pixels", layout.width,
                       layout.height);
    rc = contact_sheet_compose(desc, &layout, rgb, size, err);
    if (rc == 0) {
        char software[64];
        snprintf(software, sizeof software, "nscatter %s", NS_VERSION);
        encode_text texts[ENCODE_MAX_TEXTS];
        texts[0] = (encode_text){"Software", software};
        for (size_t i = 0; i < desc->text_count; i++)
            texts[1 + i] = desc->texts[i];
        rc = encode_png_rgb8(rgb, layout.width, layout.height, texts, 1 + desc->text_count, out,
                             err);
    }
    free(rgb);
    return rc;
}
