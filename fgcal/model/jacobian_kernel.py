"""The compiled Jacobian of a frame (fgcal.model.chain_kernel's tables and evaluation): every
column, direct and through the gravity moments, in one loop over configurations.

A column is a sum of spatial twists ``(omega, v0)`` (a point p moves by ``omega x p + v0``): the
twist of each element the name enters through, on the deformed chain, and, through the
compliances, the twist of every deflection on the frame's path times the rate of its gravity
moment. Two kinds of names change the moments (docs/model.md, Jacobians):

- a geometric parameter or a joint moves bodies: for the bodies S that joint i carries among
  those the element moves, and its twist (omega, v0) on the undeformed chain::

      d tau_i = ((omega x C_S + M_S v0) - [moves B_i] M_i (omega x o_i + v0)) x g
                - [moves B_i] omega x tau_i,          d t_i = R_i^T d tau_i

- a mass scale mu_g scales its group's masses: over the group's bodies b that joint i carries,
  with m_b their masses before the scale::

      d t_i / d mu_g = R_i^T ((sum m_b c_b - (sum m_b) o_i) x g)

The columns come out as spatial twists (N, T, 6), body twists (N, 6, T) or the rates of a point
fixed in the frame (N, 3, T), written per configuration (no (N, T, 6) array beside the output).
"""

from __future__ import annotations

import numpy as np

from ..core.compiled import compiled, view
from . import chain_kernel as ck

# What the kernel writes: spatial twists (N, T, 6), body twists (N, 6, T), a point's rates (N, 3, T).
SPATIAL, BODY, POINT = 0, 1, 2
# The rows of a Jacobian's entries (fgcal.model.chain_model.ChainModel.columns): each name enters
# through some elements (a joint through each of its motions, a rotation vector's parameter through
# one column of it) or, for a mass scale, through the moments alone (element -1).
ENTRY_ROWS = ("target", "element", "column", "feature", "moment", "mass")


@compiled
def jacobian(ints, reals, buffer, params, motion, entries, scales, frame, point, mode, out):
    """Fill ``out`` with the Jacobian of frame ``frame`` w.r.t. T names at the evaluation in
    ``buffer``. ``entries`` (6, E), rows :data:`ENTRY_ROWS`: the name's column in ``out``, the
    element it enters through, that element's column (a rotation vector's 0..2), the motion
    feature that scales it (-1: none; ``motion`` (N, 2n) or (N, 0)), the moment that scales it
    (a compliance; -1: none), and for a mass scale its parameter; ``scales`` (E,) the joint
    signs and coupling coefficients. ``point`` (3,): the point of mode POINT, in the frame."""
    rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, masses, rvec_left = ck.evaluation(
        ints, buffer, out.shape[0]
    )
    _columns(
        ints, reals, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, masses, rvec_left,
        params, motion, entries, scales, frame, point, mode, out,
    )  # fmt: skip


# The tail of a workspace's integers (fgcal.model.kinematics.Workspace): where its arrays lie.
WORK_TAIL = ("entries", "n_entries", "frame", "mode", "scales", "point", "buffer", "out", "n_conf", "n_targets",
             "n_params", "n_joints")  # fmt: skip
N_WORK_TAIL = len(WORK_TAIL)


@compiled
def forward_jacobian(params, q, motion, work_ints, work_reals):
    """chain_kernel.forward at ``q``, then :func:`jacobian`, in one call, on a workspace's two
    arrays (fgcal.model.kinematics.Workspace): ``work_ints`` the model's ``ints``, then the
    Jacobian's entries, then :data:`WORK_TAIL`; ``work_reals`` the model's ``reals``, then the
    scales, the point, the evaluation's buffer and the Jacobian ``out``, where the tail says.
    Numba unboxes every array argument at every call (50-70 ns each): five arrays where the two
    calls took fourteen. The shapes are checked here, where it costs nothing (ValueError)."""
    tail = work_ints[work_ints.shape[0] - N_WORK_TAIL :]
    at, n_entries, frame, mode, n_conf, n_targets = tail[0], tail[1], tail[2], tail[3], tail[8], tail[9]
    n_joints = tail[11]
    if params.shape[0] != tail[10] or q.shape[0] != n_conf or q.shape[1] != n_joints:
        raise ValueError("the parameters (P,) and joint values (N, n) are not of the workspace's shapes")
    if motion.shape[1] > 0 and (motion.shape[0] != n_conf or motion.shape[1] != 2 * n_joints):
        raise ValueError("the motion features (N, 2n) are not of the workspace's shape")
    rows = 6 if mode == BODY else 3
    entries = view(work_ints[at : at + 6 * n_entries], (6, n_entries))
    scales = work_reals[tail[4] : tail[4] + n_entries]
    point = work_reals[tail[5] : tail[5] + 3]
    buffer = work_reals[tail[6] : tail[7]]
    out = view(work_reals[tail[7] : tail[7] + n_conf * rows * n_targets], (n_conf, rows, n_targets))
    rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, masses, rvec_left = ck.evaluation(
        work_ints, buffer, q.shape[0]
    )
    ck.fill(
        work_ints, work_reals, params, q, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass,
        masses, rvec_left,
    )  # fmt: skip
    _columns(
        work_ints, work_reals, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, masses,
        rvec_left, params, motion, entries, scales, frame, point, mode, out,
    )  # fmt: skip


@compiled(inline=True)
def _columns(
    ints, reals, rigid, deformed, com_world, weighted, torque_world, moments, carried_mass, masses, rvec_left,
    params, motion, entries, scales, frame, point, mode, out,
):  # fmt: skip
    """:func:`jacobian` on the evaluation's arrays (chain_kernel.evaluation): its one
    implementation."""
    tables = ck.int_table(ints, ck.ELEMENTS)
    kind, param, moment, start, rvec_slot = tables[0], tables[1], tables[2], tables[4], tables[5]
    mass_param, bend = ck.int_row(ints, ck.BODIES, 1), ck.int_row(ints, ck.BENDS, 0)
    carried, moves_bend = ck.int_table(ints, ck.CARRIED), ck.int_table(ints, ck.MOVES_BEND)
    set_bodies, moved_set = ck.int_table(ints, ck.BODY_SETS), ck.int_row(ints, ck.MOVED_SET, 0)
    nominal, g = ck.real_row(ints, reals, ck.MASSES, 0), ck.real_row(ints, reals, ck.GRAVITY, 0)
    n_conf = out.shape[0]
    targets, elements, columns, features, moment_of, mass_of = (
        entries[0], entries[1], entries[2], entries[3], entries[4], entries[5]
    )  # fmt: skip
    n_targets = out.shape[1] if mode == SPATIAL else out.shape[2]
    n_links, n_bodies = bend.shape[0], masses.shape[0]
    moves_out = ck.int_row(ints, ck.ANCESTRY, frame)
    deflection_element, deflection_moment, compliance, needed, coupled = _deflections(
        moves_out, param, moment, params, n_links
    )
    n_deflections = deflection_element.shape[0]
    deflection_twists = np.zeros((n_deflections, 6))
    unit = np.zeros(6)
    rate = np.zeros(3 * n_links)
    spatial = np.empty((n_targets, 6))
    has_motion = motion.shape[1] > 0
    # The sets of bodies whose first mass moments C_S the names' moment rates need (none without
    # coupling), and whether any name bends the frame through the moments.
    n_sets = set_bodies.shape[0]
    used = np.zeros(n_sets, dtype=np.bool_)
    bending = False
    for e in range(elements.shape[0]):
        if coupled and elements[e] < 0:
            bending = True
        elif coupled and moment_of[e] < 0:
            used[moved_set[elements[e]]] = bending = True
    set_mass = np.zeros((n_links, n_sets))  # M_S
    set_moment = np.zeros((n_links, n_sets, 3))  # C_S at the configuration
    for i in range(n_links):
        for s in range(n_sets):
            if used[s]:
                for b in range(n_bodies):
                    if carried[i, b] and set_bodies[s, b]:
                        set_mass[i, s] += masses[b]
    for n in range(n_conf):
        spatial[:, :] = 0.0
        if bending:
            for i in range(n_links):
                if not needed[i]:
                    continue
                for s in range(n_sets):
                    if not used[s]:
                        continue
                    c0 = c1 = c2 = 0.0
                    for b in range(n_bodies):
                        if carried[i, b] and set_bodies[s, b]:
                            c0 += weighted[n, b, 0]
                            c1 += weighted[n, b, 1]
                            c2 += weighted[n, b, 2]
                    set_moment[i, s, 0], set_moment[i, s, 1], set_moment[i, s, 2] = c0, c1, c2
        for d in range(n_deflections if bending else 0):
            ck.twist(kind, start, rvec_slot, rvec_left, deformed, n, deflection_element[d], 0, deflection_twists[d])
        for e in range(elements.shape[0]):
            k, target = elements[e], targets[e]
            scale = scales[e]
            if k < 0:  # a mass scale: it moves the frame through the moments alone
                if coupled:
                    _mass_rates(mass_of[e], mass_param, nominal, carried, needed, com_world, rigid, bend, g, n, rate)
                    _add_bending(compliance, deflection_moment, deflection_twists, scale, rate, spatial[target])
                continue
            if features[e] >= 0:
                scale *= motion[n, features[e]] if has_motion else 0.0
            if moves_out[k] and scale != 0.0:  # (a motion term without motion: no column)
                coefficient = scale * (moments[n, moment_of[e]] if moment_of[e] >= 0 else 1.0)
                ck.twist(kind, start, rvec_slot, rvec_left, deformed, n, k, columns[e], unit)
                for c in range(6):
                    spatial[target, c] += coefficient * unit[c]
            if moment_of[e] >= 0 or not coupled or scale == 0.0:
                continue
            ck.twist(kind, start, rvec_slot, rvec_left, rigid, n, k, columns[e], unit)
            w0, w1, w2, v0, v1, v2 = unit[0], unit[1], unit[2], unit[3], unit[4], unit[5]
            s = moved_set[k]
            for i in range(n_links):
                if not needed[i]:
                    continue
                c0, c1, c2 = set_moment[i, s, 0], set_moment[i, s, 1], set_moment[i, s, 2]
                mass = set_mass[i, s]
                l0 = w1 * c2 - w2 * c1 + mass * v0
                l1 = w2 * c0 - w0 * c2 + mass * v1
                l2 = w0 * c1 - w1 * c0 + mass * v2
                frame_i = rigid[bend[i], n]
                if moves_bend[i, k]:
                    o0, o1, o2 = frame_i[0, 3], frame_i[1, 3], frame_i[2, 3]
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
                    rate[3 * i + c] = frame_i[0, c] * d0 + frame_i[1, c] * d1 + frame_i[2, c] * d2
            _add_bending(compliance, deflection_moment, deflection_twists, scale, rate, spatial[target])
        _store(mode, spatial, deformed[frame, n], point, out[n])


@compiled(inline=True)
def _deflections(moves_out, param, moment, params, n_links):
    """The deflections on a frame's path (``moves_out`` (K,)): their elements, moments and
    compliances (M,); the joints whose moments they take (L,); and whether the moments bend
    the frame at all (a compliance on the path is not zero)."""
    n_deflections = 0
    for k in range(moment.shape[0]):
        if moves_out[k] and moment[k] >= 0:
            n_deflections += 1
    element = np.empty(n_deflections, dtype=np.int64)
    of_moment = np.empty(n_deflections, dtype=np.int64)
    compliance = np.empty(n_deflections)
    needed = np.zeros(n_links, dtype=np.bool_)
    coupled = False
    d = 0
    for k in range(moment.shape[0]):
        if moves_out[k] and moment[k] >= 0:
            element[d], of_moment[d], compliance[d] = k, moment[k], params[param[k]]
            coupled = coupled or compliance[d] != 0.0
            needed[moment[k] // 3] = True
            d += 1
    return element, of_moment, compliance, needed, coupled


@compiled(inline=True)
def _mass_rates(scale_param, mass_param, nominal, carried, needed, com_world, rigid, bend, g, n, rate):
    """``rate`` (3L): d t_i / d mu of the mass scale whose parameter is ``scale_param``, at
    configuration n, for the joints ``needed``: R_i^T ((sum m_b c_b - (sum m_b) o_i) x g) over
    the scaled bodies b that joint i carries, with their masses ``nominal`` before the scale."""
    for i in range(bend.shape[0]):
        if not needed[i]:
            continue
        mass = c0 = c1 = c2 = 0.0
        for b in range(nominal.shape[0]):
            if carried[i, b] and mass_param[b] == scale_param:
                mass += nominal[b]
                c0 += nominal[b] * com_world[n, b, 0]
                c1 += nominal[b] * com_world[n, b, 1]
                c2 += nominal[b] * com_world[n, b, 2]
        frame_i = rigid[bend[i], n]
        l0, l1, l2 = c0 - mass * frame_i[0, 3], c1 - mass * frame_i[1, 3], c2 - mass * frame_i[2, 3]
        d0 = l1 * g[2] - l2 * g[1]
        d1 = l2 * g[0] - l0 * g[2]
        d2 = l0 * g[1] - l1 * g[0]
        for c in range(3):
            rate[3 * i + c] = frame_i[0, c] * d0 + frame_i[1, c] * d1 + frame_i[2, c] * d2


@compiled(inline=True)
def _add_bending(compliance, deflection_moment, deflection_twists, scale, rate, column):
    """Add to ``column`` (6,) what the moments' rates ``rate`` (3L) bend the frame by: each
    deflection's twist times its compliance and its moment's rate, times ``scale``."""
    for d in range(compliance.shape[0]):
        weight = compliance[d] * scale * rate[deflection_moment[d]]
        for c in range(6):
            column[c] += weight * deflection_twists[d, c]


@compiled(inline=True)
def _store(mode, spatial, pose, point, out):
    """Write one configuration's spatial twists ``spatial`` (T, 6) of the frame at ``pose``
    (3, 4) into ``out``: as they are (T, 6); as body twists (6, T), omega_b = R^T omega,
    v_b = R^T (omega x o + v0); or as the rates (3, T) of ``point``, omega x p + v0."""
    if mode == SPATIAL:
        out[:, :] = spatial
        return
    o0, o1, o2 = pose[0, 3], pose[1, 3], pose[2, 3]
    if mode == BODY:
        for t in range(spatial.shape[0]):
            w0, w1, w2 = spatial[t, 0], spatial[t, 1], spatial[t, 2]
            u0 = w1 * o2 - w2 * o1 + spatial[t, 3]
            u1 = w2 * o0 - w0 * o2 + spatial[t, 4]
            u2 = w0 * o1 - w1 * o0 + spatial[t, 5]
            for c in range(3):
                out[c, t] = pose[0, c] * w0 + pose[1, c] * w1 + pose[2, c] * w2
                out[3 + c, t] = pose[0, c] * u0 + pose[1, c] * u1 + pose[2, c] * u2
        return
    p0 = pose[0, 0] * point[0] + pose[0, 1] * point[1] + pose[0, 2] * point[2] + o0
    p1 = pose[1, 0] * point[0] + pose[1, 1] * point[1] + pose[1, 2] * point[2] + o1
    p2 = pose[2, 0] * point[0] + pose[2, 1] * point[1] + pose[2, 2] * point[2] + o2
    for t in range(spatial.shape[0]):
        w0, w1, w2 = spatial[t, 0], spatial[t, 1], spatial[t, 2]
        out[0, t] = w1 * p2 - w2 * p1 + spatial[t, 3]
        out[1, t] = w2 * p0 - w0 * p2 + spatial[t, 4]
        out[2, t] = w0 * p1 - w1 * p0 + spatial[t, 5]
