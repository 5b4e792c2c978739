/* refine_fit_sums.h -- the body of refine.c's hand-vectorised fit sums,
 * included once per instruction set (fit_sums_avx2, fit_sums_sse2), so that
 * both versions are one text and add the same products in the same order.
 *
 * fit_sums_body's 8 double lanes are taken as 8 / FS_W vectors of FS_W
 * lanes, each part on its own, and the sums of T^2 m apart from those of T
 * and T obs, so that the sums stay in the registers (the generic vectors
 * spill most of them). Each lane adds what fit_sums_body's lane adds, in
 * its order: the versions give the same bits (tests/host/unit/
 * test_refine_versions.c).
 *
 * The includer defines: FS_NAME (the function), FS_ATTR (its attributes),
 * FS_VD (a vector of FS_W doubles), FS_W, FS_LOAD(p) (FS_W floats at p
 * widened), FS_ZERO (a zero vector). They are undefined at the end. */
FS_ATTR static void FS_NAME(const rf_work *w, long npad, int nch, double q[3][20])
{
    const float *nx = w->a[A_NX], *ny = w->a[A_NY], *nz = w->a[A_NZ];
    for (int c = 0; c < nch; c++) {
        const float *tv = w->a[A_V0 + c], *ov = w->a[A_O0 + c];
        FS_VD acc[8 / FS_W][18];
        for (int h = 0; h < 8 / FS_W; h++) {
            FS_VD s[10];
            for (int i = 0; i < 10; i++) s[i] = FS_ZERO;
            for (long k = FS_W * h; k < npad; k += 8) {
                FS_VD n0 = FS_LOAD(nx + k), n1 = FS_LOAD(ny + k), n2 = FS_LOAD(nz + k);
                FS_VD t = FS_LOAD(tv + k), t2 = t * t;
                s[0] += t2;
                s[1] += t2 * n0;
                s[2] += t2 * n1;
                s[3] += t2 * n2;
                s[4] += t2 * (n0 * n0);
                s[5] += t2 * (n0 * n1);
                s[6] += t2 * (n0 * n2);
                s[7] += t2 * (n1 * n1);
                s[8] += t2 * (n1 * n2);
                s[9] += t2 * (n2 * n2);
            }
            memcpy(acc[h], s, sizeof s);
            for (int i = 0; i < 8; i++) s[i] = FS_ZERO;
            for (long k = FS_W * h; k < npad; k += 8) {
                FS_VD n0 = FS_LOAD(nx + k), n1 = FS_LOAD(ny + k), n2 = FS_LOAD(nz + k);
                FS_VD t = FS_LOAD(tv + k), to = t * FS_LOAD(ov + k);
                s[0] += t;
                s[1] += t * n0;
                s[2] += t * n1;
                s[3] += t * n2;
                s[4] += to;
                s[5] += to * n0;
                s[6] += to * n1;
                s[7] += to * n2;
            }
            memcpy(acc[h] + 10, s, 8 * sizeof s[0]);
        }
        for (int i = 0; i < 18; i++) {
            double sum = 0;
            for (int l = 0; l < 8; l++) sum += acc[l / FS_W][i][l % FS_W];
            q[c][i] = sum;
        }
    }
}

#undef FS_NAME
#undef FS_ATTR
#undef FS_VD
#undef FS_W
#undef FS_LOAD
#undef FS_ZERO
