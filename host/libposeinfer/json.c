/* json.c -- a small recursive-descent JSON parser and an output buffer. */
#include "json.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define JSON_MAX_DEPTH 32

typedef struct {
    const char *s;
    size_t pos;
    char *err;
    size_t errlen;
} parser;

static int fail(parser *p, const char *why)
{
    snprintf(p->err, p->errlen, "json: %s at offset %zu", why, p->pos);
    return -1;
}

static void skip_ws(parser *p)
{
    while (p->s[p->pos] == ' ' || p->s[p->pos] == '\t' || p->s[p->pos] == '\n' ||
           p->s[p->pos] == '\r')
        p->pos++;
}

static int parse_value(parser *p, json_value *v, int depth);

static int hexval(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Parse a string literal at p->pos (the opening quote) into a new buffer. */
static int parse_string(parser *p, char **out)
{
    size_t start = ++p->pos, cap = 16, len = 0;
    char *buf = malloc(cap);
    (void)start;
    if (!buf) return fail(p, "out of memory");
    for (;;) {
        unsigned char c = (unsigned char)p->s[p->pos];
        char tmp[4];
        size_t n = 0;
        if (c == '\0') {
            free(buf);
            return fail(p, "unterminated string");
        }
        if (c < 0x20) {
            free(buf);
            return fail(p, "control character in string");
        }
        if (c == '"') {
            p->pos++;
            break;
        }
        if (c == '\\') {
            char e = p->s[p->pos + 1];
            p->pos += 2;
            switch (e) {
            case '"': tmp[n++] = '"'; break;
            case '\\': tmp[n++] = '\\'; break;
            case '/': tmp[n++] = '/'; break;
            case 'b': tmp[n++] = '\b'; break;
            case 'f': tmp[n++] = '\f'; break;
            case 'n': tmp[n++] = '\n'; break;
            case 'r': tmp[n++] = '\r'; break;
            case 't': tmp[n++] = '\t'; break;
            case 'u': {
                unsigned cp = 0;
                for (int i = 0; i < 4; i++) {
                    int h = hexval(p->s[p->pos + i]);
                    if (h < 0) {
                        free(buf);
                        return fail(p, "bad \\u escape");
                    }
                    cp = cp * 16 + (unsigned)h;
                }
                p->pos += 4;
                /* Surrogates are not needed for metadata; encode them as U+FFFD. */
                if (cp == 0 || (cp >= 0xD800 && cp <= 0xDFFF)) cp = 0xFFFD;
                if (cp < 0x80)
                    tmp[n++] = (char)cp;
                else if (cp < 0x800) {
                    tmp[n++] = (char)(0xC0 | (cp >> 6));
                    tmp[n++] = (char)(0x80 | (cp & 0x3F));
                } else {
                    tmp[n++] = (char)(0xE0 | (cp >> 12));
                    tmp[n++] = (char)(0x80 | ((cp >> 6) & 0x3F));
                    tmp[n++] = (char)(0x80 | (cp & 0x3F));
                }
                break;
            }
            default:
                free(buf);
                p->pos -= 1;
                return fail(p, "bad escape");
            }
        } else {
            tmp[n++] = (char)c;
            p->pos++;
        }
        if (len + n + 1 > cap) {
            char *nb;
            cap = cap * 2 + n;
            nb = realloc(buf, cap);
            if (!nb) {
                free(buf);
                return fail(p, "out of memory");
            }
            buf = nb;
        }
        memcpy(buf + len, tmp, n);
        len += n;
    }
    buf[len] = '\0';
    *out = buf;
    return 0;
}

static int parse_number(parser *p, json_value *v)
{
    const char *start = p->s + p->pos;
    const char *q = start;
    char *end;
    /* Validate the JSON grammar first: strtod alone accepts hex, inf, nan. */
    if (*q == '-') q++;
    if (*q == '0')
        q++;
    else if (isdigit((unsigned char)*q))
        while (isdigit((unsigned char)*q)) q++;
    else
        return fail(p, "bad number");
    if (*q == '.') {
        q++;
        if (!isdigit((unsigned char)*q)) return fail(p, "bad number");
        while (isdigit((unsigned char)*q)) q++;
    }
    if (*q == 'e' || *q == 'E') {
        q++;
        if (*q == '+' || *q == '-') q++;
        if (!isdigit((unsigned char)*q)) return fail(p, "bad number");
        while (isdigit((unsigned char)*q)) q++;
    }
    errno = 0;
    v->number = strtod(start, &end);
    if (end != q || !isfinite(v->number)) return fail(p, "bad number");
    v->type = JSON_NUMBER;
    p->pos += (size_t)(q - start);
    return 0;
}

static int push_item(parser *p, json_value *v, char *key, const json_value *item)
{
    if (v->count % 8 == 0) {
        json_value *ni = realloc(v->items, (v->count + 8) * sizeof *ni);
        if (!ni) return fail(p, "out of memory");
        v->items = ni;
        if (v->type == JSON_OBJECT) {
            char **nk = realloc(v->keys, (v->count + 8) * sizeof *nk);
            if (!nk) return fail(p, "out of memory");
            v->keys = nk;
        }
    }
    v->items[v->count] = *item;
    if (v->type == JSON_OBJECT) v->keys[v->count] = key;
    v->count++;
    return 0;
}

static int parse_container(parser *p, json_value *v, int depth, int object)
{
    char close = object ? '}' : ']';
    v->type = object ? JSON_OBJECT : JSON_ARRAY;
    p->pos++;
    skip_ws(p);
    if (p->s[p->pos] == close) {
        p->pos++;
        return 0;
    }
    for (;;) {
        json_value item;
        char *key = NULL;
        memset(&item, 0, sizeof item);
        skip_ws(p);
        if (object) {
            if (p->s[p->pos] != '"') return fail(p, "expected a key");
            if (parse_string(p, &key) < 0) return -1;
            skip_ws(p);
            if (p->s[p->pos] != ':') {
                free(key);
                return fail(p, "expected ':'");
            }
            p->pos++;
        }
        if (parse_value(p, &item, depth + 1) < 0) {
            free(key);
            return -1;
        }
        if (push_item(p, v, key, &item) < 0) {
            free(key);
            json_free(&item);
            return -1;
        }
        skip_ws(p);
        if (p->s[p->pos] == ',') {
            p->pos++;
            continue;
        }
        if (p->s[p->pos] == close) {
            p->pos++;
            return 0;
        }
        return fail(p, object ? "expected ',' or '}'" : "expected ',' or ']'");
    }
}

static int parse_value(parser *p, json_value *v, int depth)
{
    if (depth > JSON_MAX_DEPTH) return fail(p, "too deeply nested");
    skip_ws(p);
    switch (p->s[p->pos]) {
    case '{': return parse_container(p, v, depth, 1);
    case '[': return parse_container(p, v, depth, 0);
    case '"': v->type = JSON_STRING; return parse_string(p, &v->string);
    case 't':
        if (strncmp(p->s + p->pos, "true", 4)) return fail(p, "bad literal");
        v->type = JSON_BOOL;
        v->number = 1;
        p->pos += 4;
        return 0;
    case 'f':
        if (strncmp(p->s + p->pos, "false", 5)) return fail(p, "bad literal");
        v->type = JSON_BOOL;
        v->number = 0;
        p->pos += 5;
        return 0;
    case 'n':
        if (strncmp(p->s + p->pos, "null", 4)) return fail(p, "bad literal");
        v->type = JSON_NULL;
        p->pos += 4;
        return 0;
    case '\0': return fail(p, "unexpected end");
    default: return parse_number(p, v);
    }
}

int json_parse(const char *text, json_value *out, char *err, size_t errlen)
{
    parser p = {text, 0, err, errlen};
    memset(out, 0, sizeof *out);
    if (parse_value(&p, out, 0) < 0) goto fail;
    skip_ws(&p);
    if (text[p.pos] != '\0') {
        fail(&p, "trailing characters");
        goto fail;
    }
    return 0;
fail:
    json_free(out);
    memset(out, 0, sizeof *out);
    return -1;
}

void json_free(json_value *v)
{
    if (!v) return;
    for (size_t i = 0; i < v->count; i++) {
        if (v->keys) free(v->keys[i]);
        json_free(&v->items[i]);
    }
    free(v->keys);
    free(v->items);
    free(v->string);
    memset(v, 0, sizeof *v);
}

const json_value *json_get(const json_value *obj, const char *key)
{
    if (!obj || obj->type != JSON_OBJECT) return NULL;
    /* Last one wins on duplicate keys, as in Python's json.loads. */
    for (size_t i = obj->count; i-- > 0;)
        if (strcmp(obj->keys[i], key) == 0) return &obj->items[i];
    return NULL;
}

/* ---- output buffer ---------------------------------------------------- */

void sb_init(sbuf *s)
{
    memset(s, 0, sizeof *s);
}
void sb_free(sbuf *s)
{
    free(s->buf);
    memset(s, 0, sizeof *s);
}
void sb_reset(sbuf *s)
{
    s->len = 0;
    if (s->buf) s->buf[0] = '\0';
}

static int sb_reserve(sbuf *s, size_t extra)
{
    size_t need = s->len + extra + 1;
    if (s->oom) return -1;
    if (need > s->cap) {
        size_t cap = s->cap ? s->cap : 128;
        char *nb;
        while (cap < need) cap *= 2;
        nb = realloc(s->buf, cap);
        if (!nb) {
            s->oom = 1;
            return -1;
        }
        s->buf = nb;
        s->cap = cap;
    }
    return 0;
}

void sb_puts(sbuf *s, const char *str)
{
    size_t n = strlen(str);
    if (sb_reserve(s, n) < 0) return;
    memcpy(s->buf + s->len, str, n + 1);
    s->len += n;
}

void sb_printf(sbuf *s, const char *fmt, ...)
{
    va_list ap;
    int n;
    va_start(ap, fmt);
    n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    if (n < 0 || sb_reserve(s, (size_t)n) < 0) return;
    va_start(ap, fmt);
    vsnprintf(s->buf + s->len, (size_t)n + 1, fmt, ap);
    va_end(ap);
    s->len += (size_t)n;
}

/* Length of the well-formed UTF-8 sequence at c (RFC 3629: no overlong
 * forms, no surrogates, nothing above U+10FFFF), or 0 when it is not one. */
static size_t utf8_len(const unsigned char *c)
{
    unsigned char lo = 0x80, hi = 0xBF;
    size_t n;
    if (c[0] < 0x80) return 1;
    if (c[0] >= 0xC2 && c[0] <= 0xDF)
        n = 2;
    else if (c[0] >= 0xE0 && c[0] <= 0xEF) {
        n = 3;
        if (c[0] == 0xE0) lo = 0xA0;
        if (c[0] == 0xED) hi = 0x9F;
    } else if (c[0] >= 0xF0 && c[0] <= 0xF4) {
        n = 4;
        if (c[0] == 0xF0) lo = 0x90;
        if (c[0] == 0xF4) hi = 0x8F;
    } else
        return 0;
    if (c[1] < lo || c[1] > hi) return 0; /* also stops at the NUL */
    for (size_t i = 2; i < n; i++)
        if (c[i] < 0x80 || c[i] > 0xBF) return 0;
    return n;
}

void sb_json_str(sbuf *s, const char *str)
{
    char tmp[8];
    const unsigned char *c = (const unsigned char *)(str ? str : "");
    sb_puts(s, "\"");
    while (*c) {
        size_t n;
        switch (*c) {
        case '"':
            sb_puts(s, "\\\"");
            c++;
            continue;
        case '\\':
            sb_puts(s, "\\\\");
            c++;
            continue;
        case '\n':
            sb_puts(s, "\\n");
            c++;
            continue;
        case '\r':
            sb_puts(s, "\\r");
            c++;
            continue;
        case '\t':
            sb_puts(s, "\\t");
            c++;
            continue;
        default: break;
        }
        if (*c < 0x20 || *c == 0x7f) {
            snprintf(tmp, sizeof tmp, "\\u%04x", *c);
            sb_puts(s, tmp);
            c++;
            continue;
        }
        /* Bytes that are not UTF-8 (a file name from a Latin-1 system, junk
         * on the socket) would make the line invalid JSON: each such byte
         * becomes U+FFFD, written as an escape (docs/poseinfer.md). */
        n = utf8_len(c);
        if (n == 0) {
            sb_puts(s, "\\ufffd");
            c++;
            continue;
        }
        memcpy(tmp, c, n);
        tmp[n] = '\0';
        sb_puts(s, tmp);
        c += n;
    }
    sb_puts(s, "\"");
}

void sb_json_num(sbuf *s, double v, int decimals)
{
    if (!isfinite(v)) {
        sb_puts(s, "null");
        return;
    }
    if (v == 0) v = 0; /* no "-0.0000" */
    sb_printf(s, "%.*f", decimals, v);
}
