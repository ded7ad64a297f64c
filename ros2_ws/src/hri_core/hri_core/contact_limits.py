"""Power and force limiting of ISO/TS 15066 (5.5.5, Annex A): is a contact trace within the
body's limits?

**The limits** (`REGION_LIMITS`): ISO/TS 15066:2016, Annex A, Table A.2, for each of its twelve
body regions the maximum permissible force of quasi-static contact F_s (N), the maximum
permissible pressure of quasi-static contact (N/cm^2; the table gives it per specific area, 29
of them, and this module keeps each region's least) and the multiplier for transient contact,
2 for force and pressure wherever the table allows transient contact. It allows none on the
skull and forehead nor on the face: the table gives them no transient multiplier, so here their
transient limit is their quasi-static one and any force above it fails at once. The judge reads
force only (a simulator gives no contact area); pressure is kept for the record.

    region                       F_s N  least p_s N/cm^2 (its area)     transient F N
    skull and forehead             130  110 (temple)                    none (= 130)
    face                            65  110 (masticatory muscle)        none (= 65)
    neck                           150  140 (neck muscle)               300
    back and shoulders             210  160 (shoulder joint)            420
    chest                          140  120 (sternum)                   280
    abdomen                        110  140 (abdominal muscle)          220
    pelvis                         180  210 (pelvic bone)               360
    upper arms and elbow joints    150  190 (deltoid muscle)            300
    lower arms and wrist joints    160  180 (forearm muscle, arm nerve) 320
    hands and fingers              140  190 (back of non-dominant hand) 280
    thighs and knees               220  220 (kneecap)                   440
    lower legs                     130  210 (calf muscle)               260

Public restatements of Table A.2 disagree in places. The figures here are those of the
restatements that quote the table row by row (one gives every row; an independent one agrees
on every force it gives). Others halve it, reading its figures as transient limits (skull
130 N transient and 65 N quasi-static; hand 140 N and 70 N): the table's force column is the
quasi-static one and transient contact may reach twice it. A 2016 vendor note gives the hand
135 N; the table's figure is 140 N. Some invent per-area force limits
the table does not have (it gives force per region only). The hand's least pressure: the table
lists the dominant and the non-dominant hand apart, and the back of the non-dominant hand, 190,
is the least; the restatement that merges the two lists 200. The lower is kept (pressure is
not judged).

**The transient rule** (`TRANSIENT_CONTACT_TIME`, 0.5 s): a contact above the quasi-static
limit is transient, and may go up to the transient limit, only if the force falls back to the
quasi-static limit or below within 0.5 s of rising above it, that is, the robot moves away
within 0.5 s; a contact that stays above longer is held (quasi-static) and fails. A contact
still above the quasi-static limit when the trace ends shows no release and fails too. Force
equal to a limit is within it (the limits are maximum permissible values). Table A.2 has no
time in it: the 0.5 s is the project's reading of the standard's transient contact (one the
body part can recoil from, released at once), `TRANSIENT_CONTACT_TIME`.

**The body parts** (`BODY_PART_SPANS`, `BODY_PART_REGIONS`): each capsule of the person
(hri_core.bodies.HUMAN_CAPSULES) spans one or more regions and is judged by the one with the
least quasi-static force. The head's sphere (radius 0.217 m round the head point) holds the
face as well as the skull: face, 65 N. The torso's capsule runs from between the hips to the
top of the sternum: pelvis, abdomen, chest (and the back behind them): abdomen, 110 N (the
chest's sternum has the least pressure, 120 N/cm^2, but the judge reads force). A shoulder's
runs from the top of the sternum to the shoulder joint, its inner ball at the neck's base:
chest 140 N, below the neck's 150 N and the shoulders' 210 N. The upper arm's runs from the
shoulder joint to the elbow: upper arms and elbow joints, 150 N. The forearm's runs from the
elbow to the wrist; Table A.2 counts the elbow with the upper arm, so upper arms and elbow
joints, 150 N, below the lower arm's 160 N. The hand's sphere round the wrist holds the wrist
and the hand: hands and fingers, 140 N. The person model has no neck, leg or foot capsule of
its own; their regions are in the table for traces whose parts map to them (`part_regions`).

**The judge** (`judge_contacts(time, part, force)`): samples k = 0..N-1 of (time (s), body
part name, normal force (N) >= 0). Each part's samples are one contact history; between two of
its samples the force is the earlier one's (held), and a part's last sample holds for no time.
Record the end of a contact as a 0 N sample (a simulator that drops a finished contact from its
list should write 0 N for every part it tracks at every step). Per region touched: the peak
force, the time above the quasi-static limit (summed over its parts), the longest contact above
it, whether any force exceeded the transient limit, whether a contact above the quasi-static
limit lasted beyond the transient rule, and a verdict with a one-line reason. No ROS import.
"""

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

TRANSIENT_CONTACT_TIME = 0.5  # s: above the quasi-static limit for longer, a contact is held
TRANSIENT_MULTIPLIER = 2.0  # Table A.2's transient multiplier, force and pressure alike


@dataclass(frozen=True)
class RegionLimit:
    """One body region of Table A.2 (module docstring).

    quasi_static_force F_s (N); quasi_static_pressure (N/cm^2), the least of the region's
    specific areas; transient_permitted: whether the table gives a transient multiplier (False
    on the skull and forehead and on the face)."""

    name: str
    quasi_static_force: float
    quasi_static_pressure: float
    transient_permitted: bool = True

    @property
    def title(self) -> str:
        """The region's name as Table A.2 writes it ('upper arms and elbow joints')."""
        return self.name.replace('_', ' ')

    @property
    def transient_force(self) -> float:
        """N: the most a transient contact may reach; the quasi-static force where the table
        allows no transient contact."""
        multiplier = TRANSIENT_MULTIPLIER if self.transient_permitted else 1.0
        return multiplier * self.quasi_static_force

    @property
    def transient_pressure(self) -> float:
        """N/cm^2: as transient_force, for the region's least pressure."""
        multiplier = TRANSIENT_MULTIPLIER if self.transient_permitted else 1.0
        return multiplier * self.quasi_static_pressure


REGION_LIMITS = {limit.name: limit for limit in (
    RegionLimit('skull_and_forehead', 130.0, 110.0, transient_permitted=False),
    RegionLimit('face', 65.0, 110.0, transient_permitted=False),
    RegionLimit('neck', 150.0, 140.0),
    RegionLimit('back_and_shoulders', 210.0, 160.0),
    RegionLimit('chest', 140.0, 120.0),
    RegionLimit('abdomen', 110.0, 140.0),
    RegionLimit('pelvis', 180.0, 210.0),
    RegionLimit('upper_arms_and_elbow_joints', 150.0, 190.0),
    RegionLimit('lower_arms_and_wrist_joints', 160.0, 180.0),
    RegionLimit('hands_and_fingers', 140.0, 190.0),
    RegionLimit('thighs_and_knees', 220.0, 220.0),
    RegionLimit('lower_legs', 130.0, 210.0),
)}

# The regions each capsule of hri_core.bodies.HUMAN_CAPSULES touches (module docstring says
# why); it is judged by the one of least quasi-static force.
BODY_PART_SPANS = {
    'head': ('skull_and_forehead', 'face'),
    'torso': ('chest', 'abdomen', 'pelvis', 'back_and_shoulders'),
    **{f'{side}_shoulder': ('chest', 'neck', 'back_and_shoulders') for side in 'lr'},
    **{f'{side}_upper_arm': ('back_and_shoulders', 'upper_arms_and_elbow_joints')
       for side in 'lr'},
    **{f'{side}_forearm': ('upper_arms_and_elbow_joints', 'lower_arms_and_wrist_joints')
       for side in 'lr'},
    **{f'{side}_hand': ('lower_arms_and_wrist_joints', 'hands_and_fingers') for side in 'lr'},
}
BODY_PART_REGIONS = {
    part: min(regions, key=lambda region: REGION_LIMITS[region].quasi_static_force)
    for part, regions in BODY_PART_SPANS.items()}


@dataclass(frozen=True)
class RegionJudgement:
    """What one region's contacts came to (module docstring).

    region: the REGION_LIMITS key; parts: the body parts of the trace judged by it;
    peak_force (N) and where it was (peak_part, peak_time s); time_above_quasi_static (s):
    how long its parts' force was above F_s, summed over the parts; longest_above_quasi_static
    (s): the longest single contact above F_s (to its release, or to the trace's end);
    exceeded_transient: a force above the transient limit; held_too_long: a contact above F_s
    longer than TRANSIENT_CONTACT_TIME or not released by the trace's end; passed and reason:
    the verdict and why, one line."""

    region: str
    parts: tuple[str, ...]
    peak_force: float
    peak_part: str
    peak_time: float
    time_above_quasi_static: float
    longest_above_quasi_static: float
    exceeded_transient: bool
    held_too_long: bool
    passed: bool
    reason: str

    @property
    def verdict(self) -> str:
        """'pass' or 'fail'."""
        return 'pass' if self.passed else 'fail'


@dataclass(frozen=True)
class _PartContacts:
    """One body part's samples judged against its region's limit (times (n,) s, forces (n,)
    N, increasing times)."""

    part: str
    peak_force: float
    peak_time: float
    time_above: float
    longest_above: float       # s, the longest contact above F_s
    longest_start: float       # s, when it rose above F_s
    released: bool             # every contact above F_s fell back before the trace's end
    unreleased_start: float    # s, when the unreleased one rose (nan when released)

    @classmethod
    def judge(cls, part: str, time: np.ndarray, force: np.ndarray,
              limit: RegionLimit) -> '_PartContacts':
        above = force > limit.quasi_static_force
        held = np.append(np.diff(time), 0.0)  # each sample's force holds to the next sample
        # Runs of consecutive samples above F_s: [start, stop) index ranges.
        edges = np.diff(np.concatenate(([0], above.astype(np.int8), [0])))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        longest, longest_start = 0.0, math.nan
        released, unreleased_start = True, math.nan
        for start, stop in zip(starts, stops, strict=True):
            if stop < len(time):  # the force fell back at sample `stop`
                duration = float(time[stop] - time[start])
            else:
                duration = float(time[stop - 1] - time[start])
                released, unreleased_start = False, float(time[start])
            if duration > longest or math.isnan(longest_start):
                longest, longest_start = duration, float(time[start])
        peak = int(np.argmax(force))
        return cls(part, float(force[peak]), float(time[peak]), float(held[above].sum()),
                   longest, longest_start, released, unreleased_start)


def _checked_trace(time, part, force, part_regions: Mapping[str, str]):
    """time (N,) s, part (N,) names, force (N,) N as arrays and a tuple, or a one-line
    ValueError."""
    if isinstance(part, str) or not isinstance(part, Sequence | np.ndarray):
        raise ValueError('part must be a sequence of body part names, one per sample')
    time = np.asarray(time, dtype=float)
    force = np.asarray(force, dtype=float)
    part = tuple(str(name) for name in part)
    if time.ndim != 1 or force.ndim != 1:
        raise ValueError(f'time and force must be 1-D arrays, got shapes {time.shape} and '
                         f'{force.shape}')
    if not len(time) == len(part) == len(force):
        raise ValueError(f'{len(time)} times, {len(part)} body parts and {len(force)} forces: '
                         'one of each per sample')
    if not np.all(np.isfinite(time)):
        raise ValueError(f'times must be finite, got {time[~np.isfinite(time)][0]} at sample '
                         f'{int(np.flatnonzero(~np.isfinite(time))[0])}')
    if not np.all(np.isfinite(force)):
        k = int(np.flatnonzero(~np.isfinite(force))[0])
        raise ValueError(f'forces must be finite, got {force[k]} N at sample {k}')
    if np.any(force < 0.0):
        k = int(np.flatnonzero(force < 0.0)[0])
        raise ValueError(f'normal forces must be >= 0 N, got {force[k]} N at sample {k}')
    for region in set(part_regions.values()):
        if region not in REGION_LIMITS:
            raise ValueError(f'unknown body region {region!r} (known: '
                             f'{", ".join(REGION_LIMITS)})')
    for name in dict.fromkeys(part):
        if name not in part_regions:
            raise ValueError(f'unknown body part {name!r} (known: {", ".join(part_regions)})')
    return time, part, force


def judge_contacts(time, part, force,
                   part_regions: Mapping[str, str] = BODY_PART_REGIONS,
                   ) -> dict[str, RegionJudgement]:
    """Judge a contact trace against Table A.2 (module docstring).

    time (N,) s, part (N,) body part names, force (N,) normal force N: sample k says part[k]
    was pressed with force[k] at time[k]. Samples of different parts may interleave in any
    order; each part's own times must increase. part_regions: body part -> REGION_LIMITS key
    (default BODY_PART_REGIONS, the person's capsules). Returns {region: RegionJudgement} for
    each region with at least one sample, in the order they first appear (empty for an empty
    trace). ValueError (one line) for forces not finite or negative, times not finite, a part
    not in part_regions (or a region not in REGION_LIMITS), a part's times not increasing,
    arrays not 1-D or of different lengths."""
    time, part, force = _checked_trace(time, part, force, part_regions)
    names = np.array(part, dtype=object)
    by_region: dict[str, list[_PartContacts]] = {}
    for name in dict.fromkeys(part):
        mask = names == name
        part_time, part_force = time[mask], force[mask]
        steps = np.diff(part_time)
        if np.any(steps <= 0.0):
            k = int(np.flatnonzero(steps <= 0.0)[0])
            raise ValueError(f'times of body part {name!r} must increase: {part_time[k + 1]:g} '
                             f's follows {part_time[k]:g} s')
        region = part_regions[name]
        by_region.setdefault(region, []).append(
            _PartContacts.judge(name, part_time, part_force, REGION_LIMITS[region]))
    return {region: _region_judgement(REGION_LIMITS[region], contacts)
            for region, contacts in by_region.items()}


def _region_judgement(limit: RegionLimit, contacts: list[_PartContacts]) -> RegionJudgement:
    """The verdict of one region from its parts' contacts: the transient limit first (the
    worst harm), then a contact never released, then one held too long."""
    peak = max(contacts, key=lambda c: c.peak_force)
    longest = max(contacts, key=lambda c: c.longest_above)
    unreleased = next((c for c in contacts if not c.released), None)
    exceeded = peak.peak_force > limit.transient_force
    too_long = unreleased is not None or longest.longest_above > TRANSIENT_CONTACT_TIME
    qs, title = limit.quasi_static_force, limit.title
    if exceeded and not limit.transient_permitted:
        reason = (f'{peak.peak_force:.1f} N on {peak.part} at {peak.peak_time:.3f} s exceeds '
                  f'the {title} limit {qs:.0f} N (Table A.2 allows no transient contact there)')
    elif exceeded:
        reason = (f'{peak.peak_force:.1f} N on {peak.part} at {peak.peak_time:.3f} s exceeds '
                  f'the {title} transient limit {limit.transient_force:.0f} N')
    elif unreleased is not None:
        reason = (f'{unreleased.part} above the {title} quasi-static limit {qs:.0f} N from '
                  f'{unreleased.unreleased_start:.3f} s to the end of the trace: no release '
                  'seen')
    elif too_long:
        reason = (f'{longest.part} above the {title} quasi-static limit {qs:.0f} N for '
                  f'{longest.longest_above:.3f} s from {longest.longest_start:.3f} s '
                  f'(transient contact ends within {TRANSIENT_CONTACT_TIME:g} s)')
    elif peak.peak_force > qs:
        reason = (f'peak {peak.peak_force:.1f} N above the quasi-static {qs:.0f} N only in '
                  f'transient contact (longest {longest.longest_above:.3f} s), within the '
                  f'transient {limit.transient_force:.0f} N')
    else:
        reason = f'peak {peak.peak_force:.1f} N within the {title} quasi-static limit {qs:.0f} N'
    return RegionJudgement(
        region=limit.name, parts=tuple(c.part for c in contacts), peak_force=peak.peak_force,
        peak_part=peak.part, peak_time=peak.peak_time,
        time_above_quasi_static=float(sum(c.time_above for c in contacts)),
        longest_above_quasi_static=longest.longest_above, exceeded_transient=exceeded,
        held_too_long=too_long, passed=not (exceeded or too_long), reason=reason)
