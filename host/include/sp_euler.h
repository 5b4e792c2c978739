/* sp_euler.h -- the conventions' Euler angles as a rotation matrix.
 *
 * R = Rz(z) Ry(y) Rx(x), body to world, angles in degrees (docs/conventions.md,
 * "Pose (Euler angles)"). The one C form of that formula: libposeinfer (the
 * refinement's starting pose), the rig tools' error statistics and programs
 * that read poseinfer's angles include it. Header-only because the rig's unit
 * tests build without libposeinfer; they check it against the conventions'
 * test vectors (tests/data/conventions_vectors.json).
 */
#ifndef SP_EULER_H
#define SP_EULER_H

#include <math.h>

static inline void sp_euler_to_matrix(const double euler_deg[3], double R[3][3])
{
    const double d = 3.14159265358979323846 / 180.0;
    double cx = cos(euler_deg[0] * d), sx = sin(euler_deg[0] * d);
    double cy = cos(euler_deg[1] * d), sy = sin(euler_deg[1] * d);
    double cz = cos(euler_deg[2] * d), sz = sin(euler_deg[2] * d);
    /* Rz(z) * Ry(y) * Rx(x), multiplied out. */
    R[0][0] = cz * cy;
    R[0][1] = cz * sy * sx - sz * cx;
    R[0][2] = cz * sy * cx + sz * sx;
    R[1][0] = sz * cy;
    R[1][1] = sz * sy * sx + cz * cx;
    R[1][2] = sz * sy * cx - cz * sx;
    R[2][0] = -sy;
    R[2][1] = cy * sx;
    R[2][2] = cy * cx;
}

#endif
