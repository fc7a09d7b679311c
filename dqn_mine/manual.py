"""Playing by hand (``python -m dqn_mine.play --manual``), as MiniWorld's ``manual_control``.

With a display, a window shows the first-person view and the map, and each key press is one
step; without one, or with ``--keys FILE`` (``-``: standard input), the keys are read as
characters from there, which is how a recording is scripted (the tests do).

=====================  ==============================
key                    action
=====================  ==============================
w, Up                  forward
s, Down                backward
a, Left                turn left
d, Right               turn right
space, e               pick up / put down / deliver
x                      no-op
q, Escape              end the episode here
=====================  ==============================
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from typing import Callable

from dqn_mine.env.interface import BACKWARD, FORWARD, INTERACT, NOOP, TURN_LEFT, TURN_RIGHT

KEYS = {"w": FORWARD, "Up": FORWARD, "s": BACKWARD, "Down": BACKWARD, "a": TURN_LEFT,
        "Left": TURN_LEFT, "d": TURN_RIGHT, "Right": TURN_RIGHT, "space": INTERACT,
        " ": INTERACT, "e": INTERACT, "x": NOOP}
STOP = {"q", "Escape"}


def manual_policy(keys: Iterator[str] | None = None) -> Callable:
    """A policy ``(env, obs, info, t) -> action`` that asks a person: None ends the episode.
    ``keys``: a source of key names (None: a window where a display exists, else stdin)."""
    if keys is None:
        keys = window_keys() if os.environ.get("DISPLAY") else stdin_keys()

    def act(env, obs, info, t):
        if isinstance(keys, Window):
            keys.show(env.render())
        for key in keys:
            if key in STOP:
                return None
            if key in KEYS:
                return KEYS[key]
        return None     # the keys ran out
    return act


def stdin_keys(stream=None) -> Iterator[str]:
    """Key names from a text stream, one character each (newlines and unknown ones skipped)."""
    stream = stream or sys.stdin
    while True:
        ch = stream.read(1)
        if not ch:
            return
        yield ch


class Window:
    """A Tk window: ``show`` a frame, then iterating waits for the next key press."""

    def __init__(self):
        import tkinter

        self.tk = tkinter.Tk()
        self.tk.title("dqn_mine: w/s/a/d or arrows move, space acts, q ends the episode")
        self.label = tkinter.Label(self.tk)
        self.label.pack()
        self.key = tkinter.StringVar()
        self.tk.bind("<Key>", lambda event: self.key.set(event.keysym))
        self.tk.protocol("WM_DELETE_WINDOW", lambda: self.key.set("Escape"))
        self._photo = None

    def show(self, frame) -> None:
        from PIL import Image, ImageTk

        self._photo = ImageTk.PhotoImage(Image.fromarray(frame))
        self.label.configure(image=self._photo)

    def __iter__(self):
        return self

    def __next__(self) -> str:
        self.key.set("")
        self.tk.wait_variable(self.key)
        return self.key.get()


def window_keys() -> Window:
    return Window()
