/* Unit tests: json.c (metadata parser, output buffer). */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include <cmocka.h>

#include "json.h"

static void parses_objects_arrays_numbers(void **state)
{
    json_value v;
    char err[128];
    (void)state;
    assert_int_equal(json_parse(" {\"a\": 1.5e2, \"b\": [1, -2, 0.25], \"c\": \"x\\n\\u00e9\", "
                                "\"d\": true, \"e\": null, \"a\": -3} ",
                                &v, err, sizeof err),
                     0);
    assert_int_equal(v.type, JSON_OBJECT);
    assert_true(json_get(&v, "a")->number == -3); /* last duplicate wins */
    const json_value *b = json_get(&v, "b");
    assert_int_equal(b->type, JSON_ARRAY);
    assert_int_equal(b->count, 3);
    assert_true(b->items[2].number == 0.25);
    assert_string_equal(json_get(&v, "c")->string, "x\n\xc3\xa9");
    assert_int_equal(json_get(&v, "d")->type, JSON_BOOL);
    assert_int_equal(json_get(&v, "e")->type, JSON_NULL);
    assert_null(json_get(&v, "zz"));
    json_free(&v);
}

static void rejects_bad_json(void **state)
{
    static const char *bad[] = {
        "",    "{",     "{\"a\" 1}",        "{\"a\": 1,}", "[1 2]", "01",       "1.",        "-",
        ".5",  "nan",   "Infinity",         "0x10",        "\"abc", "\"a\\q\"", "\"\\u12\"", "{} x",
        "tru", "1e999", "{\"a\":\"\x01\"}", NULL};
    char err[128];
    (void)state;
    for (int i = 0; bad[i]; i++) {
        json_value v;
        assert_int_equal(json_parse(bad[i], &v, err, sizeof err), -1);
        assert_non_null(strstr(err, "json: "));
        assert_non_null(strstr(err, "offset"));
    }
}

static void bounds_depth(void **state)
{
    char deep[200], err[128];
    json_value v;
    (void)state;
    memset(deep, '[', 100);
    memset(deep + 100, ']', 99);
    deep[199] = '\0';
    /* unbalanced and far too deep: an error, no stack overflow */
    assert_int_equal(json_parse(deep, &v, err, sizeof err), -1);
    assert_non_null(strstr(err, "deep"));
}

static void writes_escaped_strings_and_numbers(void **state)
{
    sbuf s;
    (void)state;
    sb_init(&s);
    sb_json_str(&s, "a\"b\\c\n\t\x01");
    assert_string_equal(s.buf, "\"a\\\"b\\\\c\\n\\t\\u0001\"");
    sb_reset(&s);
    sb_json_num(&s, NAN, 3);
    sb_puts(&s, " ");
    sb_json_num(&s, 1.23456, 2);
    sb_puts(&s, " ");
    sb_json_num(&s, -0.0, 1);
    assert_string_equal(s.buf, "null 1.23 0.0");
    sb_reset(&s);
    for (int i = 0; i < 1000; i++) sb_printf(&s, "%d,", i);
    assert_int_equal(s.len, strlen(s.buf));
    assert_false(s.oom);
    sb_free(&s);
}

/* Well-formed UTF-8 passes unchanged; every byte that is not part of it
 * becomes \ufffd, so the line stays valid JSON (issue: non-UTF-8 file names). */
static void replaces_bytes_that_are_not_utf8(void **state)
{
    static const struct {
        const char *in, *out;
    } cases[] = {
        {"n\xc3\xa4me \xe2\x82\xac \xf0\x9f\x98\x80",
         "\"n\xc3\xa4me \xe2\x82\xac \xf0\x9f\x98\x80\""},
        {"a\xff"
         "b",
         "\"a\\ufffdb\""},                                        /* never a UTF-8 byte */
        {"\xe9t\xe9.png", "\"\\ufffdt\\ufffd.png\""},             /* Latin-1 */
        {"\xc3", "\"\\ufffd\""},                                  /* cut at the end */
        {"\xe2\x82", "\"\\ufffd\\ufffd\""},                       /* cut at the end */
        {"\xc0\xaf", "\"\\ufffd\\ufffd\""},                       /* overlong '/' */
        {"\xed\xa0\x80", "\"\\ufffd\\ufffd\\ufffd\""},            /* a surrogate */
        {"\xf4\x90\x80\x80", "\"\\ufffd\\ufffd\\ufffd\\ufffd\""}, /* above U+10FFFF */
        {"\x80x", "\"\\ufffdx\""},                                /* lone continuation */
    };
    sbuf s;
    json_value v;
    char err[128];
    (void)state;
    sb_init(&s);
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        sb_reset(&s);
        sb_json_str(&s, cases[i].in);
        assert_string_equal(s.buf, cases[i].out);
        assert_int_equal(json_parse(s.buf, &v, err, sizeof err), 0);
        json_free(&v);
    }
    sb_free(&s);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(parses_objects_arrays_numbers),
        cmocka_unit_test(rejects_bad_json),
        cmocka_unit_test(bounds_depth),
        cmocka_unit_test(writes_escaped_strings_and_numbers),
        cmocka_unit_test(replaces_bytes_that_are_not_utf8),
    };
    return cmocka_run_group_tests_name("json", tests, NULL, NULL);
}
