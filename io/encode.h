/* encode.h — linear radiance images to PNG (sRGB, 8-bit) and EXR (linear float/half).
 *
 * Both encoders write to memory; the caller decides whether the bytes go to a file (CLI)
 * or a response (HTTP). Both carry caller-supplied key/value metadata: PNG as tEXt chunks
 * right after IHDR, EXR as string attributes in the header.
 *
 * Ownership: on success *out holds a malloc'd buffer the caller frees with
 * encode_buffer_free(); on failure *out is empty. Results are 0 or a negative ns_status.
 */
#ifndef NS_ENCODE_H
#define NS_ENCODE_H

#include <stddef.h>
#include <stdint.h>

#include "nscatter.h"

typedef struct encode_buffer {
    unsigned char *data;
    size_t size;
} encode_buffer;

/* One metadata entry. PNG keywords must be 1..79 printable Latin-1 characters without
 * leading/trailing spaces; values must not contain NUL. Both are checked. */
typedef struct encode_text {
    const char *key;
    const char *value;
} encode_text;

#define ENCODE_MAX_TEXTS 32

typedef enum { ENCODE_PNG = 0, ENCODE_EXR_FLOAT = 1, ENCODE_EXR_HALF = 2 } encode_format;

/* The one conversion of linear radiance to what a PNG holds, used by every 8-bit output
 * (encode_png, the contact sheet): radiance times `scale` (encode_exposure_scale), sRGB
 * transfer, clamped to [0, 1], rounded to 8 bits. NaN and negative values give 0, +Inf
 * gives 255. */
uint8_t encode_srgb8(float linear, float scale);

/* The scale 2^exposure_stops that encode_srgb8 takes. An exposure that is not a finite
 * number in [-64, 64] is refused with NS_ERR_INVALID_ARGUMENT. */
int encode_exposure_scale(float exposure_stops, float *scale, ns_error *err);

/* PNG: 8-bit RGB (encode_srgb8 of every channel), deflated by zlib. */
int encode_png(const ns_image *img, float exposure_stops, const encode_text *texts,
               size_t text_count, encode_buffer *out, ns_error *err);

/* The largest picture encode_png_rgb8 writes: larger than a render may be
 * (NS_MAX_IMAGE_SIDE, NS_MAX_PIXELS), since a contact sheet holds many renders. */
#define ENCODE_RGB8_MAX_SIDE 16384u
#define ENCODE_RGB8_MAX_PIXELS (64u * 1024u * 1024u)

/* PNG of pixels already in 8-bit sRGB: `rgb` holds width*height*3 bytes, rows top down,
 * no padding; the caller keeps it. Sizes of 0 or over the limits above are refused
 * (NS_ERR_INVALID_ARGUMENT, NS_ERR_LIMIT). Metadata as encode_png. */
int encode_png_rgb8(const uint8_t *rgb, uint32_t width, uint32_t height, const encode_text *texts,
                    size_t text_count, encode_buffer *out, ns_error *err);

/* EXR: linear R, G, B as 32-bit float (half = 0) or 16-bit half (half = 1), ZIP
 * compressed; exposure is not applied (EXR keeps the radiance the renderer produced).
 * Non-finite pixels are written as 0 so that viewers do not propagate them. */
int encode_exr(const ns_image *img, int half, const encode_text *texts, size_t text_count,
               encode_buffer *out, ns_error *err);

/* Dispatch on format. */
int encode_image(encode_format format, const ns_image *img, float exposure_stops,
                 const encode_text *texts, size_t text_count, encode_buffer *out, ns_error *err);

/* MIME type and file extension of a format. */
const char *encode_mime_type(encode_format format);

void encode_buffer_free(encode_buffer *buf); /* NULL is allowed; zeroes the struct */

#endif
