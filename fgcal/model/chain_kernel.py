"""The chain's compiled kernel: FK, gravity moments and the spatial Jacobian columns of an
elementary transform sequence (fgcal.model.ets) in loops over configurations and elements, compiled
by numba (issue 26).

NumPy evaluates the chain one element at a time over every configuration: fast per number
for thousands of configurations, but a single configuration (IK, an online update) pays a
few microseconds of dispatch for each of hundreds of small array operations. These loops do
the same arithmetic as scalars. ``cache=True`` keeps the machine code on disk, so that only
the first process after an install compiles.

The functions take plain arrays (a chain's tables, built once per chain by fgcal.model.ets.layout) and fill
preallocated outputs; fgcal.model.ets and fgcal.model.kinematics hold the meaning and call them.
Conventions: ``kind`` 0, 1, 2 rotations about x, y, z; 3, 4, 5 translations; 6 a rotation
vector (three parameters, its 3x3 rotation and left Jacobian given in ``rvec_rotation`` and
``rvec_left`` at the element's ``rvec_slot``). Index -1 means "none". A chain's tables come as
two arrays, since each array a kernel takes costs about 50 ns of dispatch at every call: the
integer ``tables`` (6, K), rows kind, param, moment, joint, start, rvec_slot, and the real
``constants`` (2, K), rows const, sign (fgcal.model.ets.layout).
"""

from __future__ import annotations

import numpy as np

from ..core.compiled import compiled


@compiled(inline=True)
def frames(tables, constants, rvec_rotation, params, q, moments, root, out):
    """Fill ``out`` (K+1, N, 3, 4) with the chain's frames at N configurations ``q`` (N, n), the
    top three rows of each 4x4 transform: ``out[k + 1]`` the frame after element k, ``out[0]``
    the top three rows of ``root`` (4, 4). ``moments`` (N, 3L) scale the deflections'
    parameters; with none, (N, 0), each is its parameter's value."""
    kind, param, moment, joint, start, rvec_slot = tables[0], tables[1], tables[2], tables[3], tables[4], tables[5]
    const, sign = constants[0], constants[1]
    n_conf = q.shape[0]
    use_moments = moments.shape[1] > 0
    # Element by element over every configuration: each pass streams through two contiguous
    # blocks of frames.
    for n in range(n_conf):
        out[0, n] = root[:3]
    for k in range(kind.shape[0]):
        s, axis = start[k], kind[k]
        if axis == 6:
            rotation = rvec_rotation[rvec_slot[k]]
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
            if param[k] >= 0:  # no moments given: the parameter's value itself
                value += params[param[k]] * (moments[n, moment[k]] if moment[k] >= 0 and use_moments else 1.0)
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
    """The gravity moments of the undeformed chain ``rigid`` (K+1, N, 3, 4): each body's centre
    of mass ``com_world`` (N, B, 3) and ``weighted`` m_b c_b, each joint's torque
    ``torque_world`` (N, L, 3) = (C_i - M_i o_i) x g, moment (N, 3L) = R_i^T tau_i, and
    ``carried_mass`` (L,) M_i."""
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


@compiled
def forward(
    tables, constants, rvec_rotation, params, q, root,
    body_frame, coms, masses, carried, bend, g, compliant,
    rigid, deformed, com_world, weighted, torque_world, moments, carried_mass,
):  # fmt: skip
    """:func:`frames` of the undeformed chain into ``rigid``, its :func:`gravity` moments and
    carried masses, and, if ``compliant``, the frames they deform into ``deformed``. One call,
    where three would each pay the dispatch of a dozen arrays (and returning an array costs
    its boxing)."""
    unbent = np.zeros(moments.shape)  # zero moments: no deflection (none at all would be the parameters')
    frames(tables, constants, rvec_rotation, params, q, unbent, root, rigid)
    gravity(rigid, body_frame, coms, masses, carried, bend, g, com_world, weighted, torque_world, moments, carried_mass)
    if compliant:
        frames(tables, constants, rvec_rotation, params, q, moments, root, deformed)


@compiled(inline=True)
def _twist(kind, start, rvec_slot, rvec_left, frames, n, k, column, out):
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


@compiled
def spatial_columns(
    tables, rvec_left, deformed, rigid,
    entries, scales, moves_out,
    motion, moments,
    deflections, deflection_compliance,
    carried, moved_set, set_bodies, moves_bend, bend, weighted, masses, carried_mass, torque_world, g,
    out,
):  # fmt: skip
    """Add to ``out`` (N, T, 6) the spatial twists of a frame w.r.t. T names, entered through
    the entries (5, E), rows target, element, column, motion feature, moment or -1, with
    their ``scales`` (E,). ``deflections`` (2, M): the element and the moment of each
    deflection on the frame's path.

    An entry's element moves the frame directly when it lies on the frame's path
    (``moves_out``): its twist on the deformed chain times its scale, its motion feature and,
    for a compliance, its moment. A geometric entry also bends every deflection on the path
    through the gravity moments it changes (kinematics.moment_derivatives' formula)::

        d tau_i = ((omega x C_S + M_S v0) - [moves B_i] M_i (omega x o_i + v0)) x g
                  - [moves B_i] omega x tau_i,          d t_i = R_i^T d tau_i

    S is the bodies joint i carries among those the element moves: element k moves the bodies
    of its set ``set_bodies[moved_set[k]]`` (S, B); a chain has few such sets, so C_S and M_S
    are summed once per joint and set, not once per entry.
    """
    kind, start, rvec_slot = tables[0], tables[4], tables[5]
    targets, elements, columns, features, moment_of = entries[0], entries[1], entries[2], entries[3], entries[4]
    deflection_element, deflection_moment = deflections[0], deflections[1]
    n_links, n_bodies = bend.shape[0], masses.shape[0]
    n_deflections = deflection_element.shape[0]
    coupled = False
    for d in range(n_deflections):
        if deflection_compliance[d] != 0.0:
            coupled = True
    needed = np.zeros(n_links, dtype=np.bool_)
    for d in range(n_deflections):
        needed[deflection_moment[d] // 3] = True
    deflection_twists = np.zeros((n_deflections, 6))
    twist = np.zeros(6)
    rate = np.zeros(3 * n_links)
    has_motion = motion.shape[1] > 0
    n_sets = set_bodies.shape[0]
    set_mass = np.zeros((n_links, n_sets))  # M_S
    set_moment = np.zeros((n_links, n_sets, 3))  # C_S at the configuration
    for i in range(n_links):
        for s in range(n_sets):
            for b in range(n_bodies):
                if carried[i, b] and set_bodies[s, b]:
                    set_mass[i, s] += masses[b]
    for n in range(deformed.shape[1]):
        if coupled:
            for i in range(n_links):
                if not needed[i]:
                    continue
                for s in range(n_sets):
                    c0 = c1 = c2 = 0.0
                    for b in range(n_bodies):
                        if carried[i, b] and set_bodies[s, b]:
                            c0 += weighted[n, b, 0]
                            c1 += weighted[n, b, 1]
                            c2 += weighted[n, b, 2]
                    set_moment[i, s, 0], set_moment[i, s, 1], set_moment[i, s, 2] = c0, c1, c2
        for d in range(n_deflections):
            _twist(kind, start, rvec_slot, rvec_left, deformed, n, deflection_element[d], 0, deflection_twists[d])
        for e in range(elements.shape[0]):
            k, target = elements[e], targets[e]
            scale = scales[e]
            if features[e] >= 0:
                scale *= motion[n, features[e]] if has_motion else 0.0
            if moves_out[k]:
                coefficient = scale * (moments[n, moment_of[e]] if moment_of[e] >= 0 else 1.0)
                _twist(kind, start, rvec_slot, rvec_left, deformed, n, k, columns[e], twist)
                for c in range(6):
                    out[n, target, c] += coefficient * twist[c]
            if moment_of[e] >= 0 or not coupled or scale == 0.0:
                continue
            _twist(kind, start, rvec_slot, rvec_left, rigid, n, k, columns[e], twist)
            w0, w1, w2, v0, v1, v2 = twist[0], twist[1], twist[2], twist[3], twist[4], twist[5]
            s = moved_set[k]
            for i in range(n_links):
                if not needed[i]:
                    continue
                c0, c1, c2 = set_moment[i, s, 0], set_moment[i, s, 1], set_moment[i, s, 2]
                mass = set_mass[i, s]
                l0 = w1 * c2 - w2 * c1 + mass * v0
                l1 = w2 * c0 - w0 * c2 + mass * v1
                l2 = w0 * c1 - w1 * c0 + mass * v2
                frame = rigid[bend[i], n]
                if moves_bend[i, k]:
                    o0, o1, o2 = frame[0, 3], frame[1, 3], frame[2, 3]
                    l0 -= carried_mass[i] * (w1 * o2 - w2 * o1 + v0)
                    l1 -= carried_mass[i] * (w2 * o0 - w0 * o2 + v1)
                    l2 -= carried_mass[i] * (w0 * o1 - w1 * o0 + v2)
                d0 = l1 * g[2] - l2 * g[1]
                d1 = l2 * g[0] - l0 * g[2]
                d2 = l0 * g[1] - l1 * g[0]
                if moves_bend[i, k]:
                    t0, t1, t2 = torque_world[n, i, 0], torque_world[n, i, 1], torque_world[n, i, 2]
                    d0 -= w1 * t2 - w2 * t1
                    d1 -= w2 * t0 - w0 * t2
                    d2 -= w0 * t1 - w1 * t0
                for c in range(3):
                    rate[3 * i + c] = frame[0, c] * d0 + frame[1, c] * d1 + frame[2, c] * d2
            for d in range(n_deflections):
                weight = deflection_compliance[d] * scale * rate[deflection_moment[d]]
                for c in range(6):
                    out[n, target, c] += weight * deflection_twists[d, c]


@compiled
def body_twists(spatial, pose, out):
    """Body twist Jacobian ``out`` (N, 6, T) of a frame at ``pose`` (N, 3 or 4, 4) from its spatial
    twists (N, T, 6): omega_b = R^T omega, v_b = R^T (omega x o + v0). ``out`` may be
    ``spatial``'s own memory (its reshape): each configuration's twists are read first."""
    twists = np.empty((spatial.shape[1], 6))
    for n in range(spatial.shape[0]):
        twists[:, :] = spatial[n]
        frame = pose[n]
        o0, o1, o2 = frame[0, 3], frame[1, 3], frame[2, 3]
        for t in range(spatial.shape[1]):
            w0, w1, w2 = twists[t, 0], twists[t, 1], twists[t, 2]
            u0 = w1 * o2 - w2 * o1 + twists[t, 3]
            u1 = w2 * o0 - w0 * o2 + twists[t, 4]
            u2 = w0 * o1 - w1 * o0 + twists[t, 5]
            for c in range(3):
                out[n, c, t] = frame[0, c] * w0 + frame[1, c] * w1 + frame[2, c] * w2
                out[n, 3 + c, t] = frame[0, c] * u0 + frame[1, c] * u1 + frame[2, c] * u2


@compiled
def point_rates(spatial, pose, point, out):
    """Jacobian ``out`` (N, 3, T) of the world position of ``point`` (3,), fixed in the frame at
    ``pose`` (N, 3 or 4, 4), from the frame's spatial twists (N, T, 6): omega x p + v0."""
    for n in range(spatial.shape[0]):
        frame = pose[n]
        p = np.zeros(3)
        for r in range(3):
            p[r] = frame[r, 0] * point[0] + frame[r, 1] * point[1] + frame[r, 2] * point[2] + frame[r, 3]
        for t in range(spatial.shape[1]):
            w0, w1, w2 = spatial[n, t, 0], spatial[n, t, 1], spatial[n, t, 2]
            out[n, 0, t] = w1 * p[2] - w2 * p[1] + spatial[n, t, 3]
            out[n, 1, t] = w2 * p[0] - w0 * p[2] + spatial[n, t, 4]
            out[n, 2, t] = w0 * p[1] - w1 * p[0] + spatial[n, t, 5]


@compiled
def element_twists(tables, rvec_left, frames, elements, columns, out):
    """Spatial unit twists ``out`` (N, E, 6) of E element columns on ``frames``."""
    kind, start, rvec_slot = tables[0], tables[4], tables[5]
    for n in range(frames.shape[1]):
        for e in range(elements.shape[0]):
            _twist(kind, start, rvec_slot, rvec_left, frames, n, elements[e], columns[e], out[n, e])
