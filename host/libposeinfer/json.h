/* json.h -- the little JSON this runtime needs: parse small documents (model
 * metadata), and build output lines into a growable buffer. */
#ifndef PI_JSON_H
#define PI_JSON_H

#include <stddef.h>

enum json_type { JSON_NULL, JSON_BOOL, JSON_NUMBER, JSON_STRING, JSON_ARRAY, JSON_OBJECT };

typedef struct json_value {
    enum json_type type;
    double number;            /* JSON_NUMBER, JSON_BOOL (0/1) */
    char *string;             /* JSON_STRING (NUL-terminated, no embedded NULs) */
    size_t count;             /* JSON_ARRAY, JSON_OBJECT: number of items */
    char **keys;              /* JSON_OBJECT: count keys */
    struct json_value *items; /* JSON_ARRAY, JSON_OBJECT: count values */
} json_value;

/* Parse text (NUL-terminated) into *out. Depth and size are bounded. Returns
 * 0, or -1 with err "json: reason at offset N". Free with json_free. */
int json_parse(const char *text, json_value *out, char *err, size_t errlen);

/* Free what json_parse allocated (not v itself). */
void json_free(json_value *v);

/* Member `key` of an object, or NULL. */
const json_value *json_get(const json_value *obj, const char *key);

/* A growable string buffer for output lines. */
typedef struct sbuf {
    char *buf;
    size_t len, cap;
    int oom; /* set when an allocation failed; contents then truncated */
} sbuf;

void sb_init(sbuf *s);
void sb_free(sbuf *s);
void sb_reset(sbuf *s);
void sb_puts(sbuf *s, const char *str);
void sb_printf(sbuf *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Append str as a JSON string literal, with quotes and escapes; each byte
 * that is not part of well-formed UTF-8 becomes \ufffd, so the output is
 * always valid UTF-8 JSON. */
void sb_json_str(sbuf *s, const char *str);
/* Append a number as JSON (non-finite values become null). */
void sb_json_num(sbuf *s, double v, int decimals);

#endif
