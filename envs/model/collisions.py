"""Collisions: which vehicles touch, by separating axes on their boxes.

Every pair of a road is checked: each automated vehicle (an oriented box) against every other
vehicle in its view (NPCs are axis-aligned: they keep their lane; other AVs are oriented), and each
NPC against the NPC ahead of it in its lane (NPCs keep their lanes, so two NPCs can only touch
there, and in a lane only the nearest one ahead can be reached first). A contact is a crash for
both parties.
"""

from __future__ import annotations

from typing import Any


def av_contacts(
    xp: Any,
    psi: Any,
    half_length: Any,
    half_width: Any,
    dx: Any,
    dy: Any,
    other_half_length: Any,
    other_half_width: Any,
    present: Any,
    other_psi: Any = None,
) -> Any:
    """(M, B) bool: AV ``b`` (heading ``psi``, half sizes (B,)) touches vehicle ``m`` at relative
    position ``dx, dy`` in the AV's frame. ``other_psi`` (M, B) is the others' heading in that frame,
    None when every other vehicle is axis-aligned (the single-AV road: a cheaper test)."""
    cs, sn = xp.cos(psi), xp.sin(psi)
    c, s = xp.abs(cs), xp.abs(sn)
    he_l, he_w, hn_l, hn_w = half_length, half_width, other_half_length, other_half_width
    if other_psi is None:
        hit = xp.abs(dx) <= hn_l + he_l * c + he_w * s
        if not xp.some(hit):  # (no vehicle overlaps the AV along the road: no contact, skip the other axes)
            return hit
        hit &= xp.abs(dy) <= hn_w + he_l * s + he_w * c
        hit &= xp.abs(dx * cs + dy * sn) <= he_l + hn_l * c + hn_w * s
        hit &= xp.abs(-dx * sn + dy * cs) <= he_w + hn_l * s + hn_w * c
        return hit & present
    # Both boxes oriented: the four axes are each box's length and width directions.
    cb, sb = xp.cos(other_psi), xp.sin(other_psi)
    rel = psi - other_psi
    rc, rs = xp.abs(xp.cos(rel)), xp.abs(xp.sin(rel))
    hit = xp.abs(dx * cb + dy * sb) <= hn_l + he_l * rc + he_w * rs
    hit &= xp.abs(-dx * sb + dy * cb) <= hn_w + he_l * rs + he_w * rc
    hit &= xp.abs(dx * cs + dy * sn) <= he_l + hn_l * rc + hn_w * rs
    hit &= xp.abs(-dx * sn + dy * cs) <= he_w + hn_l * rs + hn_w * rc
    return hit & present


def lane_contacts(xp: Any, s: Any, direction: Any, half_length: Any, leader: Any, present: Any) -> tuple[Any, Any]:
    """NPCs touching the NPC ahead of them in their lane: (follower mask (M, N), leader index (M, N),
    -1 where there is no leader)."""
    has_leader = leader >= 0
    lead = xp.where(has_leader, leader, 0)
    cols = xp.arange(s.shape[-1])[None, :]
    gap = direction * (s[lead, cols] - s) - (half_length + half_length[lead, cols])
    return has_leader & present & (gap <= 0.0), lead
