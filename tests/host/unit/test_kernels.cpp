// Unit tests: host/libposeinfer/kernels.cpp against the OpenCV calls it stands in
// for, byte for byte, on random frames, masks and sizes (fixed seeds).
#include <csetjmp>
#include <cstdarg>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <random>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "kernels.h"

// last: cmocka defines macros (fail) that clash with the C++ headers
extern "C" {
#include <cmocka.h>
}

// A frame of noise around a background colour with a few filled blobs.
static cv::Mat random_frame(std::mt19937 &rng, int w, int h)
{
    std::uniform_int_distribution<int> u(0, 255);
    cv::Mat m(h, w, CV_8UC3, cv::Scalar(u(rng), u(rng), u(rng)));
    cv::Mat noise(h, w, CV_8UC3);
    cv::randu(noise, 0, 20 + u(rng) % 40);
    m += noise;
    int blobs = u(rng) % 4;
    for (int i = 0; i < blobs; i++)
        cv::circle(m, cv::Point(u(rng) % w, u(rng) % h), 1 + u(rng) % std::max(2, std::min(w, h) / 3),
                   cv::Scalar(u(rng), u(rng), u(rng)), cv::FILLED);
    return m;
}

static void foreground_box_and_mask(void **state)
{
    (void)state;
    std::mt19937 rng(1);
    std::uniform_int_distribution<int> u(0, 1 << 20);
    for (int t = 0; t < 400; t++) {
        const int w = 1 + u(rng) % 700, h = 1 + u(rng) % 200;
        cv::Mat f = random_frame(rng, w, h);
        int lo[3], hi[3];
        for (int c = 0; c < 3; c++) {
            lo[c] = u(rng) % 256;
            hi[c] = t % 17 == 0 ? lo[c] - 1 : std::min(255, lo[c] + u(rng) % 120);  // some empty intervals
        }
        cv::Mat ref;
        cv::inRange(f, cv::Scalar(lo[0], lo[1], lo[2]), cv::Scalar(hi[0], hi[1], hi[2]), ref);
        for (int c = 0; c < 3; c++)
            if (lo[c] > hi[c]) ref.setTo(0);  // inRange of an empty interval: nothing inside
        cv::bitwise_not(ref, ref);
        const cv::Rect box = cv::boundingRect(ref);
        int x0, y0, x1, y1;
        const bool any = kern::fg_bbox(f.data, w, h, f.step[0], lo, hi, &x0, &y0, &x1, &y1);
        assert_int_equal(any, !box.empty());
        if (any) {
            assert_int_equal(x0, box.x);
            assert_int_equal(y0, box.y);
            assert_int_equal(x1, box.x + box.width - 1);
            assert_int_equal(y1, box.y + box.height - 1);
        }
        const int rx = u(rng) % w, ry = u(rng) % h;
        const int rw = 1 + u(rng) % (w - rx), rh = 1 + u(rng) % (h - ry);
        std::vector<uint8_t> mask((size_t)rw * rh);
        kern::fg_mask(f.data, f.step[0], rx, ry, rw, rh, lo, hi, mask.data());
        cv::Mat mine(rh, rw, CV_8U, mask.data());
        assert_int_equal(cv::norm(mine, ref(cv::Rect(rx, ry, rw, rh)), cv::NORM_INF), 0);
    }
}

static void closing(void **state)
{
    (void)state;
    std::mt19937 rng(2);
    std::uniform_int_distribution<int> u(0, 1 << 20);
    const int sizes[] = {1, 3, 5, 7, 9, 15, 33, 67, 131};  // past 64: shifts across words
    for (int t = 0; t < 300; t++) {
        const int w = 1 + u(rng) % 300, h = 1 + u(rng) % 200;
        cv::Mat m(h, w, CV_8U);
        cv::randu(m, 0, 256);
        cv::Mat bin = m > (128 + u(rng) % 127);  // sparse to dense speckle
        for (int i = 0; i < 3; i++)
            cv::circle(bin, cv::Point(u(rng) % w, u(rng) % h), u(rng) % 40, cv::Scalar(255), cv::FILLED);
        const int k = sizes[t % 9];
        const int shape = t % 5 == 4 ? cv::MORPH_CROSS : t % 5 == 3 ? cv::MORPH_RECT : cv::MORPH_ELLIPSE;
        cv::Mat elem = cv::getStructuringElement(shape, cv::Size(k, k));
        cv::Mat ref;
        cv::morphologyEx(bin, ref, cv::MORPH_CLOSE, elem);
        cv::Mat mine = bin.clone();
        assert_true(kern::close_binary(mine.data, w, h, elem.data, k));
        assert_int_equal(cv::norm(mine, ref, cv::NORM_INF), 0);
    }
    // an element whose row is not one run, and a mask that is not 0/255: refused, untouched
    const uint8_t ring[9] = {1, 1, 1, 1, 0, 1, 1, 1, 1};
    uint8_t mask[16] = {0, 255, 0, 0, 255, 255, 0, 0, 0, 0, 0, 0, 255, 0, 0, 0};
    assert_false(kern::close_binary(mask, 4, 4, ring, 3));
    assert_int_equal(mask[1], 255);
    const uint8_t dot[1] = {1};
    mask[0] = 7;
    assert_false(kern::close_binary(mask, 4, 4, dot, 1));
    assert_int_equal(mask[0], 7);
}

static void area_reduction(void **state)
{
    (void)state;
    std::mt19937 rng(3);
    std::uniform_int_distribution<int> u(0, 1 << 20);
    int exercised = 0;
    for (int t = 0; t < 500; t++) {
        const int dw = t % 3 ? 128 : 1 + u(rng) % 200, dh = t % 3 ? 128 : 1 + u(rng) % 200;
        const int sw = dw + u(rng) % 600, sh = t % 3 ? sw : dh + u(rng) % 600;  // square crops, mostly
        cv::Mat src(sh, sw, CV_8UC3);
        cv::randu(src, 0, 256);
        if (t % 4 == 0) cv::GaussianBlur(src, src, cv::Size(5, 5), 2);  // smooth: more sums near .5
        cv::Mat ref;
        cv::resize(src, ref, cv::Size(dw, dh), 0, 0, cv::INTER_AREA);
        cv::Mat mine(dh, dw, CV_8UC3, cv::Scalar::all(0));
        if (!kern::resize_area_c3(src.data, sw, sh, src.step[0], mine.data, dw, dh, mine.step[0])) {
            // declined: only for an integer factor on both axes
            assert_int_equal(sw % dw, 0);
            assert_int_equal(sh % dh, 0);
            continue;
        }
        exercised++;
        assert_int_equal(cv::norm(mine, ref, cv::NORM_INF), 0);
    }
    assert_true(exercised > 400);
    // a view into a larger image (row stride != width), as the crop is
    cv::Mat big(600, 700, CV_8UC3);
    cv::randu(big, 0, 256);
    cv::Mat roi = big(cv::Rect(33, 41, 307, 307)), ref, mine(128, 128, CV_8UC3);
    cv::resize(roi, ref, cv::Size(128, 128), 0, 0, cv::INTER_AREA);
    assert_true(kern::resize_area_c3(roi.data, 307, 307, roi.step[0], mine.data, 128, 128, mine.step[0]));
    assert_int_equal(cv::norm(mine, ref, cv::NORM_INF), 0);
    // enlarging and integer factors are left to cv::resize
    assert_false(kern::resize_area_c3(roi.data, 100, 100, roi.step[0], mine.data, 128, 128, mine.step[0]));
    assert_false(kern::resize_area_c3(roi.data, 256, 256, roi.step[0], mine.data, 128, 128, mine.step[0]));
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(foreground_box_and_mask),
        cmocka_unit_test(closing),
        cmocka_unit_test(area_reduction),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
