"""The chain's compiled kernel: FK and gravity moments of an elementary transform sequence
(fgcal.model.ets) in loops over configurations and elements, compiled by numba (issue 26); its
Jacobian columns are fgcal.model.jacobian_kernel's.

NumPy evaluates the chain one element at a time over every configuration: fast per number
for thousands of configurations, but a single configuration (IK, an online update) pays a
few microseconds of dispatch for each of hundreds of small array operations. These loops do
the same arithmetic as scalars. ``cache=True`` keeps the machine code on disk, so that only
the first process after an install compiles.

A robot's constant tables (its compiled model, fgcal.model.chain_model, built once per robot)
reach the kernels packed in two arrays, ``ints`` and ``reals``, and one evaluation's arrays
(fgcal.model.kinematics.KinematicsData) in one ``buffer``: numba's dispatch costs about 50 ns
per array argument at every call, which for a dozen arrays was most of a single
configuration's cost. The sections below name the tables; :func:`int_table`,
:func:`real_table` and :func:`evaluation` unpack them as views.

Element conventions: ``kind`` 0, 1, 2 rotations about x, y, z; 3, 4, 5 translations; 6 a
rotation vector (three parameters; its rotation and left Jacobian computed here from them, its
``rvec_slot`` its row among the rotation vectors). Index -1 means "none".
"""

from __future__ import annotations

import numpy as np

from ..core.compiled import compiled, view

# The sections of a compiled model: each a C-ordered 2-D table; ``ints`` starts with a header of
# three entries (offset, rows, columns) per section, the offsets of the real ones into ``reals``.
ELEMENTS = 0  # (6, K) kind, param, moment, joint, start, rvec_slot (fgcal.model.ets.Layout)
ANCESTRY = 1  # (K+1, K) 1: element k lies on the path from the root to frame f
BODIES = 2  # (2, B) each body's frame; the parameter of its mass scale (-1: none)
BENDS = 3  # (1, L) each joint's bending frame B_i
CARRIED = 4  # (L, B) 1: joint i carries body b (its motion moves it)
MOVES_BEND = 5  # (L, K) 1: element k moves the bending frame B_i
BODY_SETS = 6  # (S, B) the distinct sets of bodies an element moves
MOVED_SET = 7  # (1, K) the set element k moves
FLAGS = 8  # (1, 2) compliant (0 or 1), the number of rotation vectors R
CONSTANTS = 9  # reals (2, K) const, sign
COMS = 10  # reals (B, 3) each body's centre of mass in its frame, m
MASSES = 11  # reals (1, B) each body's mass before its scale, kg
GRAVITY = 12  # reals (1, 3) g in the root frame, m/s^2
N_SECTIONS = 13
HEADER = 3 * N_SECTIONS


@compiled(inline=True)
def int_table(ints, which):
    """The integer section ``which`` of a compiled model, a view (rows, columns)."""
    offset, rows, columns = ints[3 * which], ints[3 * which + 1], ints[3 * which + 2]
    return view(ints[offset : offset + rows * columns], (rows, columns))


@compiled(inline=True)
def int_row(ints, which, row):
    """Row ``row`` of the integer section ``which``, a view (columns,)."""
    offset, columns = ints[3 * which] + row * ints[3 * which + 2], ints[3 * which + 2]
    return ints[offset : offset + columns]


@compiled(inline=True)
def real_row(ints, reals, which, row):
    """Row ``row`` of the real section ``which``, a view (columns,)."""
    offset, columns = ints[3 * which] + row * ints[3 * which + 2], ints[3 * which + 2]
    return reals[offset : offset + columns]


@compiled(inline=True)
def real_table(ints, reals, which):
    """The real section ``which`` of a compiled model, a view (rows, columns)."""
    offset, rows, columns = ints[3 * which], ints[3 * which + 1], ints[3 * which + 2]
    return view(reals[offset : offset + rows * columns], (rows, columns))


@compiled(inline=True)
def evaluation_offsets(n_frames, n_conf, n_links, n_bodies, n_rvecs, compliant):
    """Where each array of one evaluation starts in its buffer, and the buffer's size: rigid and
    deformed frames (K+1, N, 3, 4; one array for a rigid model), com_world and weighted (N, B,
    3), torque_world (N, L, 3), moments (N, 3L), carried_mass (L,), body_masses (B,) and
    rvec_left (R, 3, 3). The arrays that grow with N come first, so each offset is a + b N
    (fgcal.model.chain_model computes a and b from this function, run as Python)."""
    frames = n_frames * n_conf * 12
    deformed = frames if compliant else 0
    com_world = deformed + frames
    weighted = com_world + n_conf * n_bodies * 3
    torque_world = weighted + n_conf * n_bodies * 3
    moments = torque_world + n_conf * n_links * 3
    carried_mass = moments + n_conf * n_links * 3
    body_masses = carried_mass + n_links
    rvec_left = body_masses + n_bodies
    size = rvec_left + 9 * n_rvecs
    return 0, deformed, com_world, weighted, torque_world, moments, carried_mass, body_masses, rvec_left, size


@compiled(inline=True)
def evaluation(ints, buffer, n_conf):
    """One evaluation's arrays, views of ``buffer`` (see :func:`evaluation_offsets`)."""
    n_elements = ints[3 * ELEMENTS + 2]
    n_links, n_bodies = ints[3 * BENDS + 2], ints[3 * BODIES + 2]
    flags = int_row(ints, FLAGS, 0)
    offsets = evaluation_offsets(n_elements + 1, n_conf, n_links, n_bodies, flags[1], flags[0])
    frames, size = (n_elements + 1, n_conf, 3, 4), (n_elements + 1) * n_conf * 12
    rigid = view(buffer[offsets[0] : offsets[0] + size], frames)
    deformed = view(buffer[offsets[1] : offsets[1] + size], frames)
    com_world = view(buffer[offsets[2] : offsets[3]], (n_conf, n_bodies, 3))
    weighted = view(buffer[offsets[3] : offsets[4]], (n_conf, n_bodies, 3))
    torque_world = view(buffer[offsets[4] : offsets[5]], (n_conf, n_links, 3))
    moments = view(buffer[offsets[5] : offsets[6]], (n_conf, 3 * n_links))
    carried_mass = buffer[offsets[6] : offsets[7]]
    body_masses = buffer[offsets[7] : offsets[8]]
    rvec_left = view(buffer[offsets[8] : offsets[9]], (flags[1], 3, 3))
    return rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, body_masses, rvec_left


@compiled(inline=True)
def rotation_vector(params, first, left, out):
    """``out`` (3, 3): the rotation Exp(r) of the rotation vector ``r = params[first:first+3]``
    (rad), or with ``left`` its left Jacobian J_l(r); fgcal.core.se3's so3_exp and
    so3_left_jacobian, with their series near 0."""
    r0, r1, r2 = params[first], params[first + 1], params[first + 2]
    theta = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if left:
        if theta < 1e-6:
            a, b = 0.5 - theta**2 / 24.0, 1.0 / 6.0 - theta**2 / 120.0
        else:
            a, b = (1.0 - np.cos(theta)) / theta**2, (theta - np.sin(theta)) / theta**3
    elif theta < 1e-8:
        a, b = 1.0 - theta**2 / 6.0, 0.5 - theta**2 / 24.0
    else:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / theta**2
    # [r]x and its square, term by term as (k @ k)[i, j] = sum_l k[i, l] k[l, j].
    k01, k02, k10, k12, k20, k21 = -r2, r1, r2, -r0, -r1, r0
    out[0, 0] = 1.0 + b * (k01 * k10 + k02 * k20)
    out[0, 1] = a * k01 + b * (k02 * k21)
    out[0, 2] = a * k02 + b * (k01 * k12)
    out[1, 0] = a * k10 + b * (k12 * k20)
    out[1, 1] = 1.0 + b * (k10 * k01 + k12 * k21)
    out[1, 2] = a * k12 + b * (k10 * k02)
    out[2, 0] = a * k20 + b * (k21 * k10)
    out[2, 1] = a * k21 + b * (k20 * k01)
    out[2, 2] = 1.0 + b * (k20 * k02 + k21 * k12)


@compiled(inline=True)
def frames(tables, constants, params, q, moments, bent, root, out):
    """Fill ``out`` (K+1, N, 3, 4) with the chain's frames at N configurations ``q`` (N, n), the
    top three rows of each 4x4 transform: ``out[k + 1]`` the frame after element k, ``out[0]``
    the top three rows of ``root`` (4, 4). ``moments`` (N, 3L) scale the deflections'
    parameters; with none, (N, 0), each is its parameter's value. Not ``bent``: every
    deflection is zero (the undeformed chain), whatever ``moments`` hold."""
    kind, param, moment, joint, start = tables[0], tables[1], tables[2], tables[3], tables[4]
    const, sign = constants[0], constants[1]
    n_conf = q.shape[0]
    use_moments = moments.shape[1] > 0
    rotation = np.empty((3, 3))
    # Element by element over every configuration: each pass streams through two contiguous
    # blocks of frames.
    for n in range(n_conf):
        out[0, n] = root[:3]
    for k in range(kind.shape[0]):
        s, axis = start[k], kind[k]
        if axis == 6:
            rotation_vector(params, param[k], False, rotation)
            for n in range(n_conf):
                for r in range(3):
                    b0, b1, b2 = out[s, n, r, 0], out[s, n, r, 1], out[s, n, r, 2]
                    for c in range(3):
                        out[k + 1, n, r, c] = b0 * rotation[0, c] + b1 * rotation[1, c] + b2 * rotation[2, c]
                    out[k + 1, n, r, 3] = out[s, n, r, 3]
            continue
        j, m = (axis + 1) % 3, (axis + 2) % 3
        for n in range(n_conf):
            value = const[k]
            if param[k] >= 0 and moment[k] >= 0:  # a deflection: no moments given, its parameter's value
                value += params[param[k]] * ((moments[n, moment[k]] if use_moments else 1.0) if bent else 0.0)
            elif param[k] >= 0:
                value += params[param[k]]
            if joint[k] >= 0:
                value += sign[k] * q[n, joint[k]]
            # Only what the element leaves as it was is copied.
            if axis < 3:
                cosine, sine = np.cos(value), np.sin(value)
                for r in range(3):
                    before_j, before_m = out[s, n, r, j], out[s, n, r, m]
                    out[k + 1, n, r, axis] = out[s, n, r, axis]
                    out[k + 1, n, r, j] = cosine * before_j + sine * before_m
                    out[k + 1, n, r, m] = cosine * before_m - sine * before_j
                    out[k + 1, n, r, 3] = out[s, n, r, 3]
            else:
                for r in range(3):
                    out[k + 1, n, r, 0] = out[s, n, r, 0]
                    out[k + 1, n, r, 1] = out[s, n, r, 1]
                    out[k + 1, n, r, 2] = out[s, n, r, 2]
                    out[k + 1, n, r, 3] = out[s, n, r, 3] + value * out[s, n, r, axis - 3]


@compiled(inline=True)
def gravity(
    rigid, body_frame, coms, masses, carried, bend, g, com_world, weighted, torque_world, moments, carried_mass
):  # fmt: skip
    """The gravity moments of the undeformed chain ``rigid`` (K+1, N, 3, 4) with the body
    ``masses`` (B,): each body's centre of mass ``com_world`` (N, B, 3) and ``weighted``
    m_b c_b, each joint's torque ``torque_world`` (N, L, 3) = (C_i - M_i o_i) x g, moment
    (N, 3L) = R_i^T tau_i, and ``carried_mass`` (L,) M_i."""
    n_bodies, n_links = masses.shape[0], bend.shape[0]
    for i in range(n_links):
        carried_mass[i] = 0.0
        for b in range(n_bodies):
            if carried[i, b]:
                carried_mass[i] += masses[b]
    for n in range(rigid.shape[1]):
        for b in range(n_bodies):
            frame = rigid[body_frame[b], n]
            for r in range(3):
                value = frame[r, 0] * coms[b, 0] + frame[r, 1] * coms[b, 1] + frame[r, 2] * coms[b, 2] + frame[r, 3]
                com_world[n, b, r] = value
                weighted[n, b, r] = masses[b] * value
        for i in range(n_links):
            frame = rigid[bend[i], n]
            l0 = -carried_mass[i] * frame[0, 3]
            l1 = -carried_mass[i] * frame[1, 3]
            l2 = -carried_mass[i] * frame[2, 3]
            for b in range(n_bodies):
                if carried[i, b]:
                    l0 += weighted[n, b, 0]
                    l1 += weighted[n, b, 1]
                    l2 += weighted[n, b, 2]
            tau0 = l1 * g[2] - l2 * g[1]
            tau1 = l2 * g[0] - l0 * g[2]
            tau2 = l0 * g[1] - l1 * g[0]
            torque_world[n, i, 0] = tau0
            torque_world[n, i, 1] = tau1
            torque_world[n, i, 2] = tau2
            for c in range(3):
                moments[n, 3 * i + c] = frame[0, c] * tau0 + frame[1, c] * tau1 + frame[2, c] * tau2


_IDENTITY = np.eye(4)  # the root of a robot's chain (numba freezes it into the code: no allocation)


@compiled
def forward(ints, reals, params, q, buffer):
    """One evaluation into ``buffer`` (:func:`evaluation`) at N configurations ``q`` (N, n): the
    left Jacobians of the rotation vectors, the undeformed chain, each body's mass (its group's
    scale applied), the gravity moments, and, for a compliant model, the chain they deform.
    One call, where several would each pay the dispatch of their arrays (and returning an
    array costs its boxing)."""
    rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, body_masses, rvec_left = evaluation(
        ints, buffer, q.shape[0]
    )
    fill(
        ints, reals, params, q, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass,
        body_masses, rvec_left,
    )  # fmt: skip


@compiled(inline=True)
def fill(
    ints, reals, params, q, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, body_masses,
    rvec_left,
):  # fmt: skip
    """:func:`forward`'s evaluation into the arrays of :func:`evaluation` (one implementation,
    which fgcal.model.jacobian_kernel.forward_jacobian runs too)."""
    tables, constants = int_table(ints, ELEMENTS), real_table(ints, reals, CONSTANTS)
    body_frame, mass_param = int_row(ints, BODIES, 0), int_row(ints, BODIES, 1)
    masses = real_row(ints, reals, MASSES, 0)
    kind, param, rvec_slot = tables[0], tables[1], tables[5]
    for k in range(kind.shape[0]):
        if kind[k] == 6:
            rotation_vector(params, param[k], True, rvec_left[rvec_slot[k]])
    for b in range(masses.shape[0]):
        body_masses[b] = masses[b] * params[mass_param[b]] if mass_param[b] >= 0 else masses[b]
    frames(tables, constants, params, q, moments, False, _IDENTITY, rigid)
    gravity(
        rigid, body_frame, real_table(ints, reals, COMS), body_masses, int_table(ints, CARRIED),
        int_row(ints, BENDS, 0), real_row(ints, reals, GRAVITY, 0),
        com_world, weighted, torque_world, moments, carried_mass,
    )  # fmt: skip
    if int_row(ints, FLAGS, 0)[0]:
        frames(tables, constants, params, q, moments, True, _IDENTITY, deformed)


@compiled(inline=True)
def twist(kind, start, rvec_slot, rvec_left, frames, n, k, column, out):
    """Spatial unit twist (omega, v0) in ``out`` (6,) of element k's column (0, or 0..2 for a
    rotation vector) on ``frames`` at configuration n."""
    before = frames[start[k], n]
    axis = kind[k]
    if axis == 6:
        left = rvec_left[rvec_slot[k]]
        for r in range(3):
            out[r] = before[r, 0] * left[0, column] + before[r, 1] * left[1, column] + before[r, 2] * left[2, column]
    elif axis < 3:
        for r in range(3):
            out[r] = before[r, axis]
    else:
        for r in range(3):
            out[r] = 0.0
            out[3 + r] = before[r, axis - 3]
        return
    # v0 = -omega x o: a point p moves by omega x (p - o).
    o0, o1, o2 = before[0, 3], before[1, 3], before[2, 3]
    out[3] = -(out[1] * o2 - out[2] * o1)
    out[4] = -(out[2] * o0 - out[0] * o2)
    out[5] = -(out[0] * o1 - out[1] * o0)
