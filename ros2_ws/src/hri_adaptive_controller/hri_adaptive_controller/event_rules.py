"""Event rules: when the hand and the tool make an event E_i of paper eq. 13. No ROS import.

The event_detector node builds an `Observation` of the hand and the tool at its rate
(separation in m, speeds in m/s, times in s) and asks `EventDetector.update` which rules fire;
each firing becomes a TaskEvent that switches to the rule's task. Rules come from YAML text
(`load_rules`; `parse_rules` for the parsed mapping): rule name -> settings, e.g.

    hand_reaches_in:          # the rule's name, also its event's unless `event` is given
      kind: approach
      task: avoid             # the task to switch to ("" = none: the arm holds still)
      when_task: [follow, follow_safe]   # fires only while one of these is the current task
      speed_of: hand
      min_speed: 0.3

Kinds and their settings (defaults in brackets):
- zone_entered / zone_left: the separation crosses `distance` m inwards / outwards. A Schmitt
  trigger around it: the hand is inside once the separation is below distance - hysteresis / 2,
  outside once it is above distance + hysteresis / 2 ([0.03] m), and a new side counts once it
  has held for `dwell` s ([0.2]). No hand counts as outside.
- approach: the hand and the tool close in, by speed (`min_speed`, m/s) or by time to contact
  (`max_time_to_contact`, s: separation over closing speed); exactly one of the two.
  `speed_of`: [closing] (the rate at which the separation shrinks, hand and tool together) or
  hand (the hand's own speed towards the tool: a robot that approaches a still hand is no
  approach). Released below min_speed - hysteresis ([0.05] m/s), or above max_time_to_contact
  + hysteresis ([0.1] s); `within` m ([any]): only at separations up to it; `dwell` s ([0.05]).
- still: the hand's speed below `max_speed` m/s for `duration` s; released above max_speed +
  hysteresis ([0.01] m/s).
- lost: no hand sample for `timeout` s, once a hand has been seen.
Every rule: `task` (required), `event` ([the rule's name]), `when_task` (a task name or a list
of them, "" for no task; [any task]), `hold_off` ([1.0] s: the least time between two firings
of the rule).

A rule fires on the rising edge of its condition, never while it holds, and only if the current
task is one of `when_task` and its previous firing is hold_off s ago or more. The condition is
tracked whatever the task: an edge that comes while `when_task` does not admit the current task
is not fired later. The current task is the one the event_manager is heading to (its pending
task during a switch), '' when idle, None while unknown (then only rules without `when_task`
fire).
"""

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import yaml

KINDS = ('zone_entered', 'zone_left', 'approach', 'still', 'lost')
SPEEDS_OF = ('closing', 'hand')
COMMON_KEYS = ('kind', 'task', 'event', 'when_task', 'hold_off')
DEFAULT_HOLD_OFF = 1.0  # s
# s: a tick that lands on a dwell, hold-off or timeout (sums of float periods) counts as there.
TIME_TOLERANCE = 1e-9


class RuleError(ValueError):
    """A rule set that cannot be used; the message is one line naming the rule."""


@dataclass(frozen=True)
class Observation:
    """The hand and the tool at `time` s.

    separation (m) or None without a hand; hand_speed and robot_speed (m/s): the hand's
    velocity towards the tool and the tool's towards the hand, along the separation (negative
    when moving apart; 0 without a hand); hand_motion: |hand velocity| (m/s); since_hand (s)
    since the last hand sample, None if none has come yet.
    """

    time: float
    separation: float | None
    hand_speed: float = 0.0
    robot_speed: float = 0.0
    hand_motion: float = 0.0
    since_hand: float | None = None

    @property
    def closing_speed(self) -> float:
        """How fast the separation shrinks (m/s)."""
        return self.hand_speed + self.robot_speed


@dataclass(frozen=True)
class ZoneCondition:
    """The hand is inside (zone_entered) or outside (zone_left) a distance, with hysteresis."""

    distance: float
    hysteresis: float
    dwell: float
    inward: bool

    @property
    def initial(self) -> bool:
        return not self.inward  # no hand: outside

    @property
    def dwell_on(self) -> float:
        return self.dwell

    @property
    def dwell_off(self) -> float:
        return self.dwell

    def holds(self, obs: Observation, held: bool) -> bool:
        was_inside = held if self.inward else not held
        sep = obs.separation
        if sep is None:
            inside = False
        elif was_inside:
            inside = sep <= self.distance + self.hysteresis / 2.0
        else:
            inside = sep < self.distance - self.hysteresis / 2.0
        return inside if self.inward else not inside

    def describe(self, obs: Observation) -> str:
        where = 'no hand' if obs.separation is None else f'separation {obs.separation:.3f} m'
        side = 'inside' if self.inward else 'outside'
        return f'{where}: {side} {self.distance:g} m (+- {self.hysteresis / 2:g}) for ' \
               f'{self.dwell:g} s'


@dataclass(frozen=True)
class ApproachCondition:
    """Hand and tool close in faster than min_speed, or time to contact below a bound; on
    after `dwell_on` s (the rule's dwell), off at once."""

    min_speed: float | None
    max_time_to_contact: float | None
    hysteresis: float
    speed_of: str
    within: float
    dwell_on: float
    initial = False
    dwell_off = 0.0

    def speed(self, obs: Observation) -> float:
        return obs.closing_speed if self.speed_of == 'closing' else obs.hand_speed

    def holds(self, obs: Observation, held: bool) -> bool:
        if obs.separation is None or obs.separation > self.within:
            return False
        speed = self.speed(obs)
        margin = self.hysteresis if held else 0.0
        if self.min_speed is not None:
            return speed >= self.min_speed - margin
        if speed <= 0.0:
            return False
        return obs.separation / speed <= self.max_time_to_contact + margin

    def describe(self, obs: Observation) -> str:
        speed = self.speed(obs)
        text = f'{self.speed_of} speed {speed:.3f} m/s at separation {obs.separation:.3f} m'
        if self.min_speed is not None:
            return f'{text} (>= {self.min_speed:g} m/s)'
        return f'{text}: time to contact {obs.separation / speed:.2f} s ' \
               f'(<= {self.max_time_to_contact:g} s)'


@dataclass(frozen=True)
class StillCondition:
    """The hand moves slower than max_speed for `dwell_on` s (the rule's duration); off at
    once."""

    max_speed: float
    dwell_on: float
    hysteresis: float
    initial = False
    dwell_off = 0.0

    def holds(self, obs: Observation, held: bool) -> bool:
        if obs.separation is None:
            return False
        return obs.hand_motion <= self.max_speed + (self.hysteresis if held else 0.0)

    def describe(self, obs: Observation) -> str:
        return f'hand speed {obs.hand_motion:.3f} m/s (< {self.max_speed:g}) for ' \
               f'{self.dwell_on:g} s'


@dataclass(frozen=True)
class LostCondition:
    """No hand sample for `timeout` s, once one has been seen."""

    timeout: float
    initial = False
    dwell_on = 0.0
    dwell_off = 0.0

    def holds(self, obs: Observation, held: bool) -> bool:
        return obs.since_hand is not None and obs.since_hand >= self.timeout - TIME_TOLERANCE

    def describe(self, obs: Observation) -> str:
        return f'no hand for {obs.since_hand:.2f} s (>= {self.timeout:g} s)'


Condition = ZoneCondition | ApproachCondition | StillCondition | LostCondition


@dataclass(frozen=True)
class Rule:
    """One rule: its name, the TaskEvent it sends (`event`, `task`), when it may fire
    (`when_task`: task names, or None for any) and its hold_off (s)."""

    name: str
    kind: str
    task: str
    event: str
    when_task: tuple[str, ...] | None
    hold_off: float
    condition: Condition

    def admits(self, current_task: str | None) -> bool:
        """Whether the rule may fire while `current_task` is the current task."""
        return self.when_task is None or (current_task is not None
                                          and current_task in self.when_task)


@dataclass(frozen=True)
class Firing:
    """A rule that fired at `time` s, and why (one line)."""

    rule: Rule
    time: float
    reason: str


class _RuleState:
    """A rule's condition: its raw value (with hysteresis), the value confirmed after the
    dwell, and when it last fired."""

    def __init__(self, rule: Rule):
        self.rule = rule
        self.raw = self.confirmed = rule.condition.initial
        self.since: float | None = None  # when the raw value began to differ from confirmed
        self.last_fired: float | None = None

    def rising_edge(self, obs: Observation) -> bool:
        """Update on `obs`; True when the confirmed condition turns on."""
        condition = self.rule.condition
        self.raw = condition.holds(obs, self.raw)
        if self.raw == self.confirmed:
            self.since = None
            return False
        if self.since is None:
            self.since = obs.time
        needed = condition.dwell_on if self.raw else condition.dwell_off
        if obs.time - self.since < needed - TIME_TOLERANCE:
            return False
        self.confirmed, self.since = self.raw, None
        return self.confirmed


class EventDetector:
    """The rules' states; `update` on each new observation returns the firings."""

    def __init__(self, rules: Sequence[Rule]):
        self.rules = tuple(rules)
        self._states = [_RuleState(rule) for rule in self.rules]
        self._time: float | None = None

    def update(self, obs: Observation, current_task: str | None) -> list[Firing]:
        """The rules that fire on `obs` while `current_task` is the current task ('' idle,
        None unknown). ValueError if time goes backwards or is not finite."""
        if not math.isfinite(obs.time):
            raise ValueError(f'time must be finite, got {obs.time}')
        if self._time is not None and obs.time < self._time:
            raise ValueError(f'time went backwards: {obs.time} s after {self._time} s')
        self._time = obs.time
        fired = []
        for state in self._states:
            if not state.rising_edge(obs):
                continue
            rule = state.rule
            if not rule.admits(current_task):
                continue
            if state.last_fired is not None \
                    and obs.time - state.last_fired < rule.hold_off - TIME_TOLERANCE:
                continue
            state.last_fired = obs.time
            fired.append(Firing(rule, obs.time, rule.condition.describe(obs)))
        return fired


# -- parsing ---------------------------------------------------------------------------------

class _UniqueKeyLoader(yaml.SafeLoader):
    """A SafeLoader that refuses a key given twice in one mapping (safe_load keeps the last)."""


def _unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False):
    keys = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in keys:
            mark = key_node.start_mark
            raise RuleError(f'rules: {key!r} is given twice (line {mark.line + 1})')
        keys.add(key)
    return loader.construct_mapping(node, deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_rules(text: str) -> tuple[Rule, ...]:
    """The rules of a YAML text (module docstring); RuleError with a one-line reason."""
    try:
        document = yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as error:
        mark = getattr(error, 'problem_mark', None)
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
        problem = getattr(error, 'problem', None) or ' '.join(str(error).split())
        raise RuleError(f'rules: not valid YAML: {problem}{where}') from None
    return parse_rules({} if document is None else document)


def parse_rules(document) -> tuple[Rule, ...]:
    """The rules of a mapping rule name -> settings; RuleError with a one-line reason."""
    if not isinstance(document, Mapping):
        raise RuleError(f'rules must be a mapping of rule name -> settings, got '
                        f'{type(document).__name__}')
    return tuple(_parse_rule(name, settings) for name, settings in document.items())


def _parse_rule(name, settings) -> Rule:
    if not isinstance(name, str) or not name:
        raise RuleError(f'rule name must be a non-empty string, got {name!r}')
    where = f'rule {name!r}'
    if not isinstance(settings, Mapping):
        raise RuleError(f'{where}: expected a mapping of settings, got '
                        f'{type(settings).__name__}')
    kind = settings.get('kind')
    if kind not in KINDS:
        raise RuleError(f'{where}: kind must be one of {", ".join(KINDS)}, got {kind!r}')
    allowed = COMMON_KEYS + _KIND_KEYS[kind]
    unknown = [key for key in settings if key not in allowed]
    if unknown:
        raise RuleError(f'{where}: unknown setting {unknown[0]!r} (settings of {kind}: '
                        f'{", ".join(allowed)})')
    reader = _Settings(where, settings)
    if 'task' not in settings:
        raise RuleError(f'{where}: task is missing (the task to switch to; "" for none)')
    task = reader.string('task', allow_empty=True)
    event = reader.string('event') if 'event' in settings else name
    when = settings.get('when_task')
    if when is None:
        when_task = None
    elif isinstance(when, str):
        when_task = (when,)
    elif isinstance(when, list) and when and all(isinstance(w, str) for w in when):
        when_task = tuple(when)
    else:
        raise RuleError(f'{where}: when_task must be a task name ("" for none) or a list of '
                        f'them, got {when!r}')
    hold_off = reader.number('hold_off', DEFAULT_HOLD_OFF, 's', strict=False)
    return Rule(name, kind, task, event, when_task, hold_off, _CONDITIONS[kind](reader, kind))


class _Settings:
    """Typed reads of one rule's settings, each failure a RuleError naming the rule."""

    def __init__(self, where: str, settings: Mapping):
        self.where = where
        self.settings = settings

    def number(self, key: str, default: float | None, unit: str, strict: bool = True,
               required: bool = False) -> float | None:
        """settings[key] as a finite float > 0 (strict) or >= 0; `default` if absent."""
        if key not in self.settings:
            if required:
                raise RuleError(f'{self.where}: {key} is missing ({unit})')
            return default
        value = self.settings[key]
        valid = isinstance(value, int | float) and not isinstance(value, bool) \
            and math.isfinite(value) and (value > 0 if strict else value >= 0)
        if not valid:
            raise RuleError(f'{self.where}: {key} must be a number {"> 0" if strict else ">= 0"}'
                            f' ({unit}), got {value!r}')
        return float(value)

    def string(self, key: str, allow_empty: bool = False) -> str:
        value = self.settings[key]
        if not isinstance(value, str) or not (value or allow_empty):
            raise RuleError(f'{self.where}: {key} must be a {"" if allow_empty else "non-empty "}'
                            f'string, got {value!r}')
        return value


def _zone(reader: _Settings, kind: str) -> ZoneCondition:
    distance = reader.number('distance', None, 'm', required=True)
    hysteresis = reader.number('hysteresis', 0.03, 'm', strict=False)
    if hysteresis >= 2.0 * distance:
        raise RuleError(f'{reader.where}: hysteresis {hysteresis:g} m must be below twice the '
                        f'distance {distance:g} m (the zone would have no inside)')
    return ZoneCondition(distance, hysteresis, reader.number('dwell', 0.2, 's', strict=False),
                         inward=kind == 'zone_entered')


def _approach(reader: _Settings, kind: str) -> ApproachCondition:
    given = [key for key in ('min_speed', 'max_time_to_contact') if key in reader.settings]
    if len(given) != 1:
        raise RuleError(f'{reader.where}: give exactly one of min_speed (m/s) and '
                        f'max_time_to_contact (s), got {len(given)}')
    min_speed = reader.number('min_speed', None, 'm/s')
    max_time = reader.number('max_time_to_contact', None, 's')
    default_hysteresis = 0.05 if min_speed is not None else 0.1
    hysteresis = reader.number('hysteresis', default_hysteresis,
                               'm/s' if min_speed is not None else 's', strict=False)
    if min_speed is not None and hysteresis >= min_speed:
        raise RuleError(f'{reader.where}: hysteresis {hysteresis:g} m/s must be below '
                        f'min_speed {min_speed:g} m/s')
    speed_of = reader.settings.get('speed_of', 'closing')
    if speed_of not in SPEEDS_OF:
        raise RuleError(f'{reader.where}: speed_of must be one of {", ".join(SPEEDS_OF)}, got '
                        f'{speed_of!r}')
    return ApproachCondition(min_speed, max_time, hysteresis, speed_of,
                             reader.number('within', math.inf, 'm'),
                             reader.number('dwell', 0.05, 's', strict=False))


def _still(reader: _Settings, kind: str) -> StillCondition:
    return StillCondition(reader.number('max_speed', None, 'm/s', required=True),
                          reader.number('duration', None, 's', required=True),
                          reader.number('hysteresis', 0.01, 'm/s', strict=False))


def _lost(reader: _Settings, kind: str) -> LostCondition:
    return LostCondition(reader.number('timeout', None, 's', required=True))


_KIND_KEYS = {
    'zone_entered': ('distance', 'hysteresis', 'dwell'),
    'zone_left': ('distance', 'hysteresis', 'dwell'),
    'approach': ('min_speed', 'max_time_to_contact', 'speed_of', 'hysteresis', 'within',
                 'dwell'),
    'still': ('max_speed', 'duration', 'hysteresis'),
    'lost': ('timeout',),
}
_CONDITIONS = {'zone_entered': _zone, 'zone_left': _zone, 'approach': _approach,
               'still': _still, 'lost': _lost}
