/* The rows [row0, row1) of a JPEG, decoded grey with libjpeg-turbo's fast integer IDCT (as simplejpeg's
 * fastdct): rows above row0 are skipped (their entropy decoding only), rows from row1 on are not read at all.
 * Built by jpegrows.py on first use (cc -O2 -shared -fPIC ... -ljpeg); libjpeg-turbo >= 1.5 (jpeg_skip_scanlines).
 * A libjpeg error (a stream it cannot read: broken, or a colour space it cannot turn grey) returns 1, a warning
 * (corrupt data: a truncated or damaged stream) 3, each with libjpeg's message in msg. */
#include <setjmp.h>
#include <stdio.h>
#include <string.h>

#include <jpeglib.h>

struct aao_error {
    struct jpeg_error_mgr mgr;
    jmp_buf jump;
    char msg[JMSG_LENGTH_MAX];
};

static void aao_error_exit(j_common_ptr cinfo) {
    struct aao_error *e = (struct aao_error *)cinfo->err;
    (*cinfo->err->format_message)(cinfo, e->msg);
    longjmp(e->jump, 1);
}

static void aao_emit_message(j_common_ptr cinfo, int level) {
    if (level < 0) { /* a warning: corrupt data; the first one is the message */
        struct aao_error *e = (struct aao_error *)cinfo->err;
        if (cinfo->err->num_warnings++ == 0) (*cinfo->err->format_message)(cinfo, e->msg);
    }
}

/* Rows [row0, row1) into out (height rows of width bytes); the other rows of out are left as they are.
 * 0 ok, 1 unreadable (msg), 3 corrupt data (msg), 2 not width x height grey: *actual_width, *actual_height
 * say what it is. */
int aao_jpeg_rows(const unsigned char *data, unsigned long size, unsigned char *out, int width, int height,
                  int row0, int row1, char *msg, int msglen, int *actual_width, int *actual_height) {
    struct jpeg_decompress_struct d;
    struct aao_error e;
    d.err = jpeg_std_error(&e.mgr);
    e.mgr.error_exit = aao_error_exit;
    e.mgr.emit_message = aao_emit_message;
    e.msg[0] = 0;
    if (setjmp(e.jump)) {
        snprintf(msg, msglen, "%s", e.msg);
        jpeg_destroy_decompress(&d);
        return 1;
    }
    jpeg_create_decompress(&d);
    jpeg_mem_src(&d, data, size);
    jpeg_read_header(&d, TRUE);
    d.out_color_space = JCS_GRAYSCALE;
    d.dct_method = JDCT_IFAST;
    jpeg_start_decompress(&d);
    *actual_width = (int)d.output_width;
    *actual_height = (int)d.output_height;
    if ((int)d.output_width != width || (int)d.output_height != height || d.output_components != 1) {
        snprintf(msg, msglen, "decoded %ux%u (%d components), expected %dx%d grey", d.output_width,
                 d.output_height, d.output_components, width, height);
        jpeg_destroy_decompress(&d);
        return 2;
    }
    if (row0 > 0) jpeg_skip_scanlines(&d, (JDIMENSION)row0);
    while ((int)d.output_scanline < row1) {
        JSAMPROW rows[16];
        int n = row1 - (int)d.output_scanline < 16 ? row1 - (int)d.output_scanline : 16;
        for (int k = 0; k < n; k++) rows[k] = out + ((size_t)d.output_scanline + k) * (size_t)width;
        jpeg_read_scanlines(&d, rows, (JDIMENSION)n);
    }
    if (e.mgr.num_warnings) {
        snprintf(msg, msglen, "%s", e.msg);
        jpeg_destroy_decompress(&d);
        return 3;
    }
    jpeg_destroy_decompress(&d); /* the rows from row1 on are never read */
    return 0;
}
