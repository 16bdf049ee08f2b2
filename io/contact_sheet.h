/* contact_sheet.h — many images on one labelled PNG: one cell per image in a grid, each
 * image (box-filtered down when larger than the cell) over its lines of text. A cell
 * without an image is an empty placeholder with its note ("queued", "failed", ...) and its
 * lines. Used by the service for a sweep's sheet (GET /v1/sweeps/{id}/sheet.png).
 *
 *   contact_sheet_cell cells[2] = {
 *       {.image = &img0, .lines = (const char *[]){"/materials/wax/g=0.2", "812 ms"},
 *        .line_count = 2},
 *       {.lines = (const char *[]){"/materials/wax/g=0.5"}, .line_count = 1,
 *        .note = "running", .width = 256, .height = 256},
 *   };
 *   encode_buffer png;
 *   int rc = contact_sheet_png(&(contact_sheet_desc){.cells = cells, .cell_count = 2},
 *                              &png, &err);
 *
 * Layout, in pixels (every cell has the same size):
 *
 *   +- CONTACT_SHEET_GAP around the sheet and between cells ---------------------+
 *   |  +-------- cell_width --------+        +----------------------------+       |
 *   |  | image area: the image,     |        |                            |       |
 *   |  | centred, image_height tall |        |                            |       |
 *   |  +----------------------------+        +----------------------------+       |
 *   |  | label area: the lines,     |        |                            |       |
 *   |  | label_height tall          |        |                            |       |
 *   |  +----------------------------+        +----------------------------+       |
 *
 *   cell_width   = max(CONTACT_SHEET_MIN_CELL_WIDTH, widest image after downscaling)
 *   image_height = tallest image after downscaling
 *   label_height = 0 when no cell has lines, else
 *                  2 * CONTACT_SHEET_LABEL_PAD + CONTACT_SHEET_LINE_HEIGHT * (most lines)
 *   cell i sits in column i % columns, row i / columns, at
 *   (GAP + column * (cell_width + GAP), GAP + row * (cell_height + GAP)).
 *
 * Pixels: an image's pixels are encode_srgb8 (the PNG encoder's conversion) of its linear
 * radiance times 2^exposure_stops; a downscaled pixel is the mean of the linear radiance of
 * its box (a NaN in the box gives 0, like a NaN pixel in a PNG). Text is stb_easy_font's
 * ASCII font, one line per entry of `lines`, left aligned; a byte outside printable ASCII
 * is drawn as '?' (one '?' per UTF-8 sequence). A line too long for the cell ends in "..."
 * and nothing of it is drawn outside its cell's label area.
 *
 * Ownership: every input stays the caller's and is only read during the call. Results are
 * 0 or a negative ns_status with err naming the problem: NS_ERR_INVALID_ARGUMENT for a
 * malformed desc (no cells, an image without pixels, lines counted but not given, a bad
 * exposure), NS_ERR_LIMIT for more than CONTACT_SHEET_MAX_CELLS cells, more than
 * CONTACT_SHEET_MAX_LINES lines in a cell, or a sheet over CONTACT_SHEET_MAX_SIDE a side or
 * CONTACT_SHEET_MAX_PIXELS in all.
 */
#ifndef NS_CONTACT_SHEET_H
#define NS_CONTACT_SHEET_H

#include <stddef.h>
#include <stdint.h>

#include "encode.h"
#include "nscatter.h"

#define CONTACT_SHEET_MAX_CELLS 1024u
#define CONTACT_SHEET_MAX_LINES 64u
#define CONTACT_SHEET_MAX_SIDE ENCODE_RGB8_MAX_SIDE     /* 16384 */
#define CONTACT_SHEET_MAX_PIXELS ENCODE_RGB8_MAX_PIXELS /* 64 Mi */
#define CONTACT_SHEET_DEFAULT_CELL_SIDE 256u

#define CONTACT_SHEET_GAP 8u             /* around the sheet and between cells */
#define CONTACT_SHEET_MIN_CELL_WIDTH 64u /* so that a short label fits beside a tiny image */
#define CONTACT_SHEET_LINE_HEIGHT 12u    /* stb_easy_font's line advance */
#define CONTACT_SHEET_LABEL_PAD 4u       /* above the first line, below the last, at the sides */

/* The colours, 8-bit sRGB (exposed for the tests). */
#define CONTACT_SHEET_SHEET_RGB 48, 48, 48       /* gaps between the cells */
#define CONTACT_SHEET_CELL_RGB 16, 16, 16        /* a cell around its image, its label area */
#define CONTACT_SHEET_TEXT_RGB 236, 236, 236     /* the lines */
#define CONTACT_SHEET_PLACEHOLDER_RGB 72, 72, 72 /* an image not there (yet) */
#define CONTACT_SHEET_NOTE_RGB 180, 180, 120     /* a placeholder's note */

typedef struct contact_sheet_cell {
    const ns_image *image;    /* NULL: a placeholder */
    const char *const *lines; /* line_count lines under the image; a NULL entry is an
                                 empty line; may be NULL when line_count is 0 */
    size_t line_count;        /* 0..CONTACT_SHEET_MAX_LINES */
    const char *note;         /* placeholder only: written in its middle; NULL: none */
    /* Placeholder only: the size of the image it stands for (downscaled like an image), so
     * that a sheet of unfinished cells has its final layout. 0: the whole image area, or
     * max_cell_side square when no cell has a size. */
    uint32_t width, height;
} contact_sheet_cell;

typedef struct contact_sheet_desc {
    const contact_sheet_cell *cells;
    size_t cell_count;      /* 1..CONTACT_SHEET_MAX_CELLS */
    uint32_t columns;       /* 0: the count that makes the sheet closest to square; more
                               columns than cells: one row */
    uint32_t max_cell_side; /* 0: CONTACT_SHEET_DEFAULT_CELL_SIDE. An image wider or taller
                               is box-filtered down by the smallest integer factor that
                               fits it */
    float exposure_stops;   /* as encode_png's: radiance times 2^exposure_stops */
    /* contact_sheet_png: metadata written after the "Software" text it always writes. */
    const encode_text *texts;
    size_t text_count; /* 0..ENCODE_MAX_TEXTS - 1 */
} contact_sheet_desc;

typedef struct contact_sheet_layout {
    uint32_t width, height; /* the whole sheet */
    uint32_t columns, rows;
    uint32_t cell_width, cell_height; /* cell_height = image_height + label_height */
    uint32_t image_height, label_height;
    uint32_t max_cell_side; /* the one used (the default filled in) */
} contact_sheet_layout;

/* Where one cell and its picture land on the sheet. */
typedef struct contact_sheet_place {
    uint32_t cell_x, cell_y;   /* the cell's top left corner */
    uint32_t label_y;          /* the top of its label area */
    uint32_t image_x, image_y; /* the picture's top left corner (centred in the image area) */
    uint32_t image_width, image_height; /* the picture after downscaling (or placeholder) */
    uint32_t factor;                    /* the box filter's side: 1 when not downscaled */
} contact_sheet_place;

/* Checks desc and computes its layout. */
int contact_sheet_layout_of(const contact_sheet_desc *desc, contact_sheet_layout *out,
                            ns_error *err);

/* Where cell `index` (< desc->cell_count) lands in `layout` (from contact_sheet_layout_of
 * of the same desc). */
contact_sheet_place contact_sheet_place_of(const contact_sheet_desc *desc,
                                           const contact_sheet_layout *layout, size_t index);

/* The sheet's pixels in caller-owned `rgb`: layout->width * layout->height * 3 bytes
 * (rgb_size says how many there are; fewer is NS_ERR_INVALID_ARGUMENT), rows top down. */
int contact_sheet_compose(const contact_sheet_desc *desc, const contact_sheet_layout *layout,
                          uint8_t *rgb, size_t rgb_size, ns_error *err);

/* Layout, compose and encode_png_rgb8 in one call, with a tEXt "Software" (nscatter and
 * its version) before desc->texts. On success *out holds the PNG (free with
 * encode_buffer_free); on failure it is empty. */
int contact_sheet_png(const contact_sheet_desc *desc, encode_buffer *out, ns_error *err);

#endif
