"""A person's gamepad and keyboard, read from Meshcat, as the station's joystick and feeder command.

``MeshcatJoystick`` stands where the scripted joystick (``station_units``) or the simulated
operator (``simulated_operator``) stands: it drives each unit's ``joystick`` input (3 stick axes
in [-1, 1], through the unit's TeleoperationMapper, world or catheter mapping) and the feeder's
``v_insert_cmd`` (1, m/s). Every ``period`` seconds it reads, from the Meshcat the person has
open in a browser:

* the gamepad (``Meshcat.GetGamepad()``: the browser's standard mapping, sent once the person
  has pressed a button or moved a stick in the Meshcat window): the left stick is stick axes 0
  (right = +) and 1 (up = +), the right stick's horizontal axis is stick axis 2; the right
  trigger feeds, the left trigger retracts (analogue); RB selects the next magnet, B centres the
  keyboard's stick, Start quits. The sticks' values are absolute: the magnet turns while a
  stick is held and stops when it springs back.
* the keyboard, as Meshcat buttons with key codes (``Meshcat.AddButton(name, keycode)``: each
  key press, or a click on the button in Meshcat's control panel, counts one click; a held key
  repeats). A browser only reports presses, not releases, so the keys move a virtual stick that
  stays where it was put, like a throttle: each press moves one axis (or the feeder command) by
  ``key_step`` towards +1 or -1; Space centres the stick and stops the feeder; N selects the
  next magnet; Escape quits; R starts the live view over after the watchdog paused it (read by
  the live view, ``experiments/teleop.py``). ``KEY_MAP`` lists the keys. Meshcat counts a
  button's clicks but not their order, so the presses read in one period apply in ``KEY_MAP``
  order: a Space read with moves centres the stick (the stop wins; a person who pressed Space
  and then W within one period, or while the simulation lagged, presses W again).

What reaches the station is the sum of the two, clipped to [-1, 1]; the stick drives only the
selected unit (the others get zero), the feeder command is scaled by ``feeder_speed`` (so it
never exceeds the feeder's limit, 20 mm/s: four presses). With the feeder's ``end_stop``
connected (``end_stops``: the input ``feeder_inserted_length``), a feeder command against the stop the feeder sits at is
dropped (the keyboard's back to zero, the gamepad's trigger ignored): presses of feed with the
whole chain out, or of retract at the retraction stop, add nothing, and the command shown is
what the chain can follow.

Everything read is discrete state, so the outputs are functions of the context (state output
ports) and a run is reproducible from the inputs injected into Meshcat.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

from ballchain.systems.feeder import FeederSpec


@dataclass(frozen=True)
class Key:
    """One keyboard binding: a Meshcat button (label, JavaScript ``KeyboardEvent.code``)."""

    label: str
    code: str
    action: str  # "axis", "feed", "centre", "next", "quit", "reset" (read by the live view, not here)
    index: int = 0  # the stick axis for "axis"
    sign: float = 1.0


KEY_MAP: tuple[Key, ...] = (
    Key("stick 0 + (D)", "KeyD", "axis", 0, +1.0),
    Key("stick 0 - (A)", "KeyA", "axis", 0, -1.0),
    Key("stick 1 + (W)", "KeyW", "axis", 1, +1.0),
    Key("stick 1 - (S)", "KeyS", "axis", 1, -1.0),
    Key("stick 2 + (E)", "KeyE", "axis", 2, +1.0),
    Key("stick 2 - (Q)", "KeyQ", "axis", 2, -1.0),
    Key("feed (ArrowUp)", "ArrowUp", "feed", 0, +1.0),
    Key("retract (ArrowDown)", "ArrowDown", "feed", 0, -1.0),
    Key("centre stick, stop feeder (Space)", "Space", "centre"),
    Key("next magnet (N)", "KeyN", "next"),
    Key("quit (Escape)", "Escape", "quit"),
    Key("start over after a stop (R)", "KeyR", "reset"),
)

# The browser's standard gamepad mapping (https://w3c.github.io/gamepad/#remapping).
PAD_LEFT_X, PAD_LEFT_Y, PAD_RIGHT_X = 0, 1, 2
PAD_B, PAD_RB, PAD_LT, PAD_RT, PAD_START = 1, 5, 6, 7, 9
PAD_PRESSED = 0.5  # a button counts as pressed above this value


def pad_command(axes: Sequence[float], buttons: Sequence[float]) -> tuple[np.ndarray, float]:
    """The stick axes (3,) and the feeder command (in [-1, 1]) that a gamepad's state asks for.

    Args:
        axes: the gamepad's axes (browser convention: a stick's y axis is + downwards).
        buttons: the gamepad's button values in [0, 1] (the triggers are analogue).
    """
    def get(values, k):
        return float(values[k]) if len(values) > k else 0.0

    stick = np.array([get(axes, PAD_LEFT_X), -get(axes, PAD_LEFT_Y), get(axes, PAD_RIGHT_X)])
    return np.clip(stick, -1.0, 1.0), float(np.clip(get(buttons, PAD_RT) - get(buttons, PAD_LT), -1.0, 1.0))


class MeshcatJoystick(LeafSystem):
    """Stick axes and a feeder command from a person's gamepad and keyboard in Meshcat.

    Output ports:
        joystick_<unit>: (3,) stick axes in [-1, 1] for each unit in ``unit_names`` (zero for
            the units not selected).
        v_insert_cmd: (1,) feeder speed command [m/s].
        selected_unit: (1,) index into ``unit_names`` of the unit the stick drives.
        quit: (1,) 1.0 once the person asked to quit (Escape, the quit button, or Start).

    Input ports (with ``end_stops``):
        feeder_inserted_length: (1,) the feeder's ``inserted_length`` [m].

    State (discrete, updated every ``period`` s and at initialisation): the keyboard's stick
    (3) and feeder command (1), the combined stick (3) and feeder command (1) sent, the selected
    unit, the quit flag, the gamepad buttons' pressed flags (for their press edges) and the
    button click counts seen so far (the clicks since the last update are the difference).

    Args:
        meshcat: the Meshcat the person uses.
        unit_names: the units' names, in the order "next magnet" cycles through them.
        period: how often Meshcat is read [s].
        key_step: how far one key press moves a keyboard axis (of the full range 1).
        feeder_speed: the feeder speed at full command [m/s] (the stepper feeder's limit).
        keys: the keyboard bindings (``KEY_MAP``).
        end_stops: None, or the feeder's ``end_stops()`` (retraction stop, insertion stop,
            tolerance) [m]: the input ``feeder_inserted_length`` is declared, and a feeder
            command against the stop the feeder sits at is dropped.
    """

    def __init__(self, meshcat, unit_names: Sequence[str], period: float = 0.02, key_step: float = 0.25,
                 feeder_speed: float | None = None, keys: Sequence[Key] = KEY_MAP,
                 end_stops: tuple[float, float, float] | None = None) -> None:
        super().__init__()
        if not unit_names:
            raise ValueError("MeshcatJoystick needs at least one unit name")
        if not period > 0 or not 0 < key_step <= 1:
            raise ValueError(f"MeshcatJoystick: period must be > 0 and key_step in (0, 1], got {period}, {key_step}")
        self.set_name("meshcat_joystick")
        self._meshcat = meshcat
        self.unit_names = list(unit_names)
        self._key_step = float(key_step)
        self._feeder_speed = float(FeederSpec().max_speed if feeder_speed is None else feeder_speed)
        self.keys = tuple(keys)
        for key in self.keys:
            meshcat.AddButton(key.label, key.code)  # also resets its click count to zero
        self._pad_buttons = (PAD_B, PAD_RB, PAD_START)
        n_keys, n_pad = len(self.keys), len(self._pad_buttons)
        # State layout (one vector: the update reads and writes all of it together).
        self._i_kb = slice(0, 4)  # keyboard stick (3), keyboard feeder command (1)
        self._i_out = slice(4, 8)  # combined stick (3), combined feeder command (1)
        self._i_unit, self._i_quit = 8, 9
        self._i_pad = slice(10, 10 + n_pad)
        self._i_clicks = slice(10 + n_pad, 10 + n_pad + n_keys)
        self._state = self.DeclareDiscreteState(BasicVector(np.zeros(10 + n_pad + n_keys)))
        self._end_stops = None if end_stops is None else tuple(float(v) for v in end_stops)
        self._length_port = self.DeclareVectorInputPort("feeder_inserted_length", 1) if end_stops else None
        # The outputs are the state's alone (no feedthrough from the feeder's length: no loop).
        state_only = {self.xd_ticket()}
        self._joystick_ports = [self.DeclareVectorOutputPort(f"joystick_{n}", 3, self._make_calc_joystick(k),
                                                             prerequisites_of_calc=state_only)
                                for k, n in enumerate(self.unit_names)]
        self.DeclareVectorOutputPort("v_insert_cmd", 1, self._calc_feeder, prerequisites_of_calc=state_only)
        self.DeclareVectorOutputPort("selected_unit", 1, self._calc_selected, prerequisites_of_calc=state_only)
        self.DeclareVectorOutputPort("quit", 1, self._calc_quit, prerequisites_of_calc=state_only)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._initialize)

    # ------------------------------------------------------------------------------ reading
    def _clicks(self) -> np.ndarray:
        return np.array([self._meshcat.GetButtonClicks(k.label) for k in self.keys], float)

    def _initialize(self, context, discrete_state):
        # Clicks made before the run starts (or before a re-initialisation) do not count.
        x = np.zeros(discrete_state.get_vector(self._state).size())
        x[self._i_clicks] = self._clicks()
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
        return EventStatus.Succeeded()

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._state).get_value().copy()
        clicks = self._clicks()
        # A count below the last one: the button was re-added (its count reset to zero).
        new = np.where(clicks >= x[self._i_clicks], clicks - x[self._i_clicks], clicks)
        x[self._i_clicks] = clicks
        kb = x[self._i_kb]
        unit, quit_ = int(round(x[self._i_unit])), x[self._i_quit]
        for key, n in zip(self.keys, new):
            if n <= 0:
                continue
            if key.action == "axis":
                kb[key.index] += key.sign * self._key_step * n
            elif key.action == "feed":
                kb[3] += key.sign * self._key_step * n
            elif key.action == "centre":
                kb[:] = 0.0
            elif key.action == "next":
                unit = (unit + int(n)) % len(self.unit_names)
            elif key.action == "quit":
                quit_ = 1.0
        kb = np.clip(kb, -1.0, 1.0)
        pad = self._meshcat.GetGamepad()
        stick, feed = np.zeros(3), 0.0
        if pad.index is not None:
            stick, feed = pad_command(pad.axes, pad.button_values)
            values = pad.button_values
            pressed = np.array([float(len(values) > b and values[b] > PAD_PRESSED) for b in self._pad_buttons])
            edge = (pressed > 0.5) & (x[self._i_pad] < 0.5)
            if edge[0]:
                kb[:] = 0.0
            if edge[1]:
                unit = (unit + 1) % len(self.unit_names)
            if edge[2]:
                quit_ = 1.0
            x[self._i_pad] = pressed
        out = np.clip(kb + np.append(stick, feed), -1.0, 1.0)
        stop = 0.0 if self._length_port is None else end_stop(self._length_port.Eval(context)[0], *self._end_stops)
        if stop * out[3] > 0:  # against the stop the feeder sits at: dropped, no wind-up
            kb[3] = 0.0 if stop * kb[3] > 0 else kb[3]
            out[3] = 0.0
        x[self._i_kb] = kb
        x[self._i_out] = out
        x[self._i_unit], x[self._i_quit] = unit, quit_
        discrete_state.get_mutable_vector(self._state).SetFromVector(x)
        return EventStatus.Succeeded()

    # ------------------------------------------------------------------------------ outputs
    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._state).get_value()

    def _make_calc_joystick(self, k: int):
        def calc(context, output):
            x = self._x(context)
            selected = int(round(x[self._i_unit])) == k
            output.SetFromVector(x[self._i_out][:3] if selected else np.zeros(3))
        return calc

    def _calc_feeder(self, context, output):
        output.SetAtIndex(0, self._x(context)[self._i_out][3] * self._feeder_speed)

    def _calc_selected(self, context, output):
        output.SetAtIndex(0, self._x(context)[self._i_unit])

    def _calc_quit(self, context, output):
        output.SetAtIndex(0, self._x(context)[self._i_quit])

    def get_joystick_output_port(self, unit_name: str):
        """The ``joystick_<unit_name>`` output port (3)."""
        return self._joystick_ports[self.unit_names.index(unit_name)]

    def quit_requested(self, context) -> bool:
        """Whether the person asked to quit (in this system's context)."""
        return self._x(context)[self._i_quit] > 0.5

    def selected_unit(self, context) -> str:
        """The name of the unit the stick drives now."""
        return self.unit_names[int(round(self._x(context)[self._i_unit]))]

    def remove_buttons(self) -> None:
        """Delete this system's buttons from Meshcat (when the live run ends)."""
        for key in self.keys:
            self._meshcat.DeleteButton(key.label, strict=False)


def end_stop(length: float, low: float, high: float, tolerance: float) -> int:
    """-1 when the inserted ``length`` [m] is at the retraction stop ``low``, +1 at the insertion
    stop ``high``, 0 between (within ``tolerance`` of a stop counts as at it)."""
    return -1 if length <= low + tolerance else (1 if length >= high - tolerance else 0)


def key_map_text(keys: Sequence[Key] = KEY_MAP) -> str:
    """The keyboard and gamepad bindings, as lines for the console."""
    lines = ["keyboard (in the Meshcat window; each press moves the stick by a step, it stays there):"]
    lines += [f"  {k.code:10s} {k.label.rsplit(' (', 1)[0]}" for k in keys]
    lines += ["gamepad (press a button in the Meshcat window first so that the browser reports it):",
              "  left stick  stick axes 0 (right +) and 1 (up +); right stick (horizontal): stick axis 2",
              "  RT / LT     feed / retract (analogue)",
              "  RB next magnet; B centre the keyboard's stick; Start quit"]
    return "\n".join(lines)


def key_map_compact(keys: Sequence[Key] = KEY_MAP, per_line: int = 3) -> list[str]:
    """The bindings in a few short lines (for a panel on the page): a key pair of one axis (or of
    the feeder) as "D/A stick 0 +/-", the others as "Space centre stick, stop feeder"."""
    entries, seen = [], set()
    for k in keys:
        if (k.action, k.index) in seen:
            continue
        pair = [q for q in keys if q.action == k.action and q.index == k.index] if k.action in ("axis", "feed") else [k]
        seen.add((k.action, k.index))
        codes = "/".join(q.code.removeprefix("Key") for q in pair)
        words = [q.label.rsplit(" (", 1)[0] for q in pair]
        if len(pair) == 2 and k.action == "axis":
            words = [f"{words[0][:-2]} +/-"]
        entries.append(f"{codes} {' / '.join(words)}")
    lines = ["   ".join(entries[i:i + per_line]) for i in range(0, len(entries), per_line)]
    return lines + ["gamepad: left stick axes 0, 1; right stick axis 2; RT/LT feed/retract; RB next; B centre; "
                    "Start quit"]
