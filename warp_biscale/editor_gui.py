"""The bi-scale editor's window (``warp-biscale edit TARGET``): a pyvista window around a headless
`editor.Editor` (Wu 2011 §4 and Fig. 1a; Iwasaki 2012 §6). docs/editor.md describes it for users.

    +------------------------------+----------------------+
    |                              |  the tile, 3 x 3     |
    |  the large-scale frame       |  periods, coloured   |
    |  (Editor.image8)             |  by material         |
    |                              +----------------------+
    +------------------------------+  looking inside (i): |
    |  tabs: tile | material 0 ... |  NDF on a sphere,    |
    |  sliders of the current tab  |  polar slice of f-bar|
    +------------------------------+----------------------+

A slider calls ``editor.set(name, value, coarse=True)`` while it moves (a coarse bake for geometry) and
``editor.refine()`` when it is released; a drag is one undo step. On a height field, a left drag on the
tile paints (raise / lower / smooth, the brush's radius and strength on the "view" tab). The error
against the ground truth is computed in a second process (the backends keep scratch buffers per object,
so they may not be used from two threads at once) and shown when it arrives.

    w = open_editor(Editor("heightfield"), off_screen=True)   # what the tests drive
    w.screenshot("edit.png"); w.close()
    edit("pyramid", output="design.toml")                      # the command: a window until closed

Offscreen drawing uses EGL (no X server): `VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow` is set before
VTK loads when no window is asked for, as in `viewer`.
"""

from __future__ import annotations

import hashlib
import math
import os
import queue
import time
from dataclasses import dataclass

import numpy as np

from .io import atomic_path, check_output
from .viewer import _ensure_offscreen_gl, _has_display, tile_polydata

__all__ = ["EditorWindow", "open_editor", "edit", "Control", "controls_of", "to_slider", "from_slider", "TruthWorker",
           "TRUTH_FACETS", "TRUTH_DIRECTIONS"]

# The ground truth the error is measured against: small enough to come back in about a second on a
# 2-core CPU (0.9 s for a pyramid), fine enough that the SG bake's error, not the truth's noise, shows.
TRUTH_FACETS = 1 << 14
TRUTH_DIRECTIONS = 8

BRUSH_MODES = ("off", "raise", "lower", "smooth")
PANEL_HEIGHT = 300  # pixels of the control panel under the frame
COLUMNS = 3  # sliders a row on the panel
ORANGE, CYAN = (1.0, 0.55, 0.1), (0.3, 0.85, 1.0)


# ------------------------------------------------------------------------------------------------ controls


@dataclass
class Control:
    """One slider. `key` is an editor parameter's name, with ":0".. ":2" for an RGB component, or
    "view.*" for the window's own settings; the slider runs over [lo, hi] in `scale` units: "real",
    "log" (log10 of the value), "int", "choice" (an index into `choices`), "bool" (0 / 1)."""

    key: str
    label: str
    lo: float
    hi: float
    scale: str
    choices: tuple | None = None
    help: str = ""
    bounds: tuple | None = None  # a log slider's value range (10**lo, 10**hi rounded may fall outside it)

    @property
    def name(self) -> str:
        return self.key.partition(":")[0]

    @property
    def component(self) -> int | None:
        _, sep, c = self.key.partition(":")
        return int(c) if sep else None


def controls_of(parameters) -> dict:
    """Editor parameters → {group: [Control]}: numbers as sliders (log10 where the range spans two decades
    or more), a choice or bool as a slider over its values, an RGB as three sliders."""
    out: dict = {}
    for p in parameters:
        short = p.name.partition(".")[2]
        row = out.setdefault(p.group, [])
        if p.kind == "rgb":
            row += [Control(f"{p.name}:{c}", f"{short} {'RGB'[c]}", 0.0, 1.0, "real", help=p.help) for c in range(3)]
        elif p.kind == "choice":
            row.append(Control(p.name, short, 0, len(p.choices) - 1, "choice", tuple(p.choices), p.help))
        elif p.kind == "bool":
            row.append(Control(p.name, short, 0, 1, "bool", (False, True), p.help))
        elif p.kind == "int":
            row.append(Control(p.name, short, p.lo, p.hi, "int", help=p.help))
        elif p.lo > 0 and p.hi / p.lo >= 100:
            row.append(Control(p.name, short, math.log10(p.lo), math.log10(p.hi), "log", help=p.help,
                               bounds=(p.lo, p.hi)))
        else:
            row.append(Control(p.name, short, p.lo, p.hi, "real", help=p.help))
    return out


def to_slider(c: Control, value) -> float:
    """A parameter's value → its slider position."""
    if c.component is not None:
        return float(value[c.component])
    if c.scale in ("choice", "bool"):
        return float(c.choices.index(value))
    if c.scale == "log":
        return math.log10(value)
    return float(value)


def from_slider(c: Control, position: float, current):
    """A slider position → the parameter's value (snapped to an int or a choice; `current` gives an RGB's
    other components)."""
    if c.component is not None:
        rgb = list(current)
        rgb[c.component] = float(np.clip(position, 0.0, 1.0))
        return tuple(rgb)
    if c.scale in ("choice", "bool"):
        return c.choices[int(np.clip(round(position), 0, len(c.choices) - 1))]
    if c.scale == "int":
        return int(np.clip(round(position), c.lo, c.hi))
    if c.scale == "log":
        return float(np.clip(10.0 ** position, *c.bounds))
    return float(np.clip(position, c.lo, c.hi))


def shown(c: Control, value) -> str:
    if c.component is not None:
        return f"{value[c.component]:.2f}"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


# ------------------------------------------------------------------------------------------------ the truth


def _truth_main():
    """The ground-truth worker, a process of its own (`TruthWorker`): pickled (key, tile, materials, backend)
    jobs on stdin, pickled (key, GroundTruth or error text, seconds) results on stdout."""
    import pickle
    import sys

    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # what the libraries print (Warp's banner) goes to stderr, not into the results
    from .truth import ground_truth

    while True:
        try:
            key, tile, materials, backend = pickle.load(sys.stdin.buffer)
        except EOFError:
            return
        t0 = time.perf_counter()
        try:
            gt = ground_truth(tile, materials, facets=TRUTH_FACETS, directions=TRUTH_DIRECTIONS, backend=backend)
        except Exception as exc:  # shown in the window; the worker goes on with the next design
            gt = f"{type(exc).__name__}: {exc}"
        pickle.dump((key, gt, time.perf_counter() - t0), out)
        out.flush()


class TruthWorker:
    """Ground truths computed in a second Python process, keyed by the design's tile and materials (its
    `cache`). A process, not a thread: a backend keeps scratch buffers per object, so one may not bake here
    while it computes a truth there. One job is in flight at a time; of those asked for meanwhile, only the
    newest is sent next. (A plain subprocess, not multiprocessing: spawning would import the caller's
    main script again.)"""

    def __init__(self, backend: str):
        import subprocess
        import sys
        import threading

        self.backend = backend
        self.process = subprocess.Popen(
            [sys.executable, "-c", "from warp_biscale.editor_gui import _truth_main; _truth_main()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        self.cache: dict = {}  # key → (GroundTruth or error text, seconds)
        self.arrived: queue.Queue = queue.Queue()
        self.in_flight = None
        self.next = None
        # A thread only reads the pipe (no backend, no VTK): the window takes results from `arrived`.
        threading.Thread(target=self._read, daemon=True, name="ground truth reader").start()

    def _read(self):
        import pickle

        while True:
            try:
                self.arrived.put(pickle.load(self.process.stdout))
            except (EOFError, OSError, ValueError, pickle.UnpicklingError):
                return

    def _send(self, job):
        import pickle

        self.in_flight = job[0]
        try:
            pickle.dump((*job, self.backend), self.process.stdin)
            self.process.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            self.cache[job[0]] = (f"the ground-truth process stopped: {exc}", 0.0)
            self.in_flight = None

    def request(self, key, tile, materials) -> None:
        if key in self.cache or key == self.in_flight:
            return
        job = (key, tile, list(materials))
        if self.in_flight is None:
            self._send(job)
        else:
            self.next = job  # replaces an older wish

    def poll(self, timeout: float = 0.0) -> bool:
        """Collect what has arrived (waiting up to `timeout` s for it) → whether anything did."""
        got = False
        if self.in_flight is not None and self.process.poll() is not None and self.arrived.empty():
            # the worker died (out of memory, a crash in a kernel): say so instead of waiting for ever
            self.cache[self.in_flight] = (f"the ground-truth process stopped (exit code {self.process.returncode})",
                                          0.0)
            self.in_flight = self.next = None
            return True
        while True:
            try:
                key, gt, seconds = self.arrived.get(timeout=timeout) if timeout > 0 and not got else \
                    self.arrived.get_nowait()
            except queue.Empty:
                return got
            self.cache[key] = (gt, seconds)
            self.in_flight = None
            got = True
            if self.next is not None:
                job, self.next = self.next, None
                if job[0] not in self.cache:
                    self._send(job)

    def close(self) -> None:
        try:
            self.process.stdin.close()
        except OSError:
            pass
        self.process.kill()  # a truth half computed is of no use once the window is gone
        self.process.wait(timeout=10)


def design_key(tile, materials) -> str:
    """What a ground truth depends on: the tile (triangles, material ids, colour weights, period) and the
    small-scale BRDFs; not the bake's quality or the light."""
    h = hashlib.blake2b(digest_size=16)
    for a in (tile.vertices, tile.faces, tile.material_ids, tile.colors, np.asarray(tile.period)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr(list(materials)).encode())
    return h.hexdigest()


# ------------------------------------------------------------------------------------------------ the window


def _abort(obj, tag):
    """Stop an event here: the interactor style (camera) and pyvista's own handlers do not see it."""
    obj.GetCommand(tag).SetAbortFlag(1)


class EditorWindow:
    """The editor's window (module docstring). `plotter` is the pyvista Plotter; `renderers` maps "frame",
    "panel", "tile", "ndf", "polar" to its viewports; `sliders` maps the current tab's control keys to their
    vtkSliderWidgets; `status` is the last message shown."""

    def __init__(self, editor, off_screen=False, window_size=None, output=None, truth=True):
        if off_screen:
            _ensure_offscreen_gl()
        import pyvista as pv  # (imported only to draw: VTK takes about a second to load)

        self.pv = pv
        self.editor = editor
        self.output = None if output is None else os.fspath(output)
        self.status = ""
        self.tab = "tile" if editor.family is not None else "material 0"
        self.inside = False
        self.brush = {"mode": "off", "radius": 0.1, "strength": 0.1}
        self.theta_i = 30.0  # the polar slice's ωi, degrees from the normal
        self.shots = 0
        self._stroke = None  # (x, y) of the last dab of a brush stroke
        self._painting = False  # the left button went down on the tile with a brush on
        self._coarse = False  # the frame shows a coarse bake that refine() has still to replace
        self.truth = TruthWorker(editor.backend.name) if truth else None
        self.sliders: dict = {}
        self._controls: dict = {}
        self._picker = None  # a vtkCellPicker on the tile, made at the first pick
        self._updating = False  # sliders being made: their first callback is not an edit

        fw, fh = editor.width, editor.height
        # At the window's natural size the frame is shown at its own pixel size (at most 1280 x 800), beside
        # and above room enough for the tile and the panel; the viewports are fractions of the window, so a
        # resized window (or another `window_size`) scales all of them alike.
        s = min(1.0, 1280 / fw, 800 / fh)
        frame_px = (max(1, round(fw * s)), max(1, round(fh * s)))
        left = max(frame_px[0], 600)
        right = max(420, round(0.8 * left))
        natural = (left + right, frame_px[1] + PANEL_HEIGHT)
        self.plotter = pv.Plotter(shape=(1, 5), window_size=tuple(int(x) for x in window_size or natural),
                                  off_screen=off_screen, border=False, title="warp_biscale editor")
        self.renderers = dict(zip(("frame", "panel", "tile", "ndf", "polar"), self.plotter.renderers))
        # (frame width, left column width, frame height) as fractions of the window
        self._split = (frame_px[0] / natural[0], left / natural[0], frame_px[1] / natural[1])
        self._layout()

        self._setup_frame()
        self._setup_panel()
        self._setup_tile()
        self._setup_inside()
        self._setup_events()
        self.refresh("bake")

    # ---------------------------------------------------------------- layout
    def _layout(self):
        """Viewports in window fractions: the frame above the panel on the left, the tile (and the inside
        views below it when they are on) on the right."""
        fx, split_x, split_y = self._split
        x0 = (split_x - fx) / 2  # the frame centred over the panel
        r = self.renderers
        r["frame"].SetViewport(x0, 1 - split_y, x0 + fx, 1.0)
        r["panel"].SetViewport(0.0, 0.0, split_x, 1 - split_y)
        if self.inside:
            r["tile"].SetViewport(split_x, 0.6, 1.0, 1.0)
            r["ndf"].SetViewport(split_x, 0.25, 1.0, 0.6)
            r["polar"].SetViewport(split_x, 0.0, 1.0, 0.25)
        else:
            r["tile"].SetViewport(split_x, 0.0, 1.0, 1.0)
            for k in ("ndf", "polar"):
                r[k].SetViewport(0.0, 0.0, 0.0, 0.0)  # hidden: an empty viewport draws nothing
        for k in ("ndf", "polar"):
            r[k].SetDraw(self.inside)

    def _use(self, name):
        self.plotter.subplot(0, list(self.renderers).index(name))
        return self.renderers[name]

    # ---------------------------------------------------------------- the frame
    def _setup_frame(self):
        ren = self._use("frame")
        ren.set_background("black")
        self.frame_text = self.plotter.add_text("", position="upper_left", font_size=9, color="white", shadow=True,
                                                name="frame_text")
        self.message = self.plotter.add_text("", position="lower_left", font_size=9, color="white", shadow=True,
                                             name="message")

    def _show_frame(self):
        pv = self.pv
        tex = pv.Texture(np.ascontiguousarray(self.editor.image8()))
        tex.interpolate = True
        ren = self.renderers["frame"]
        ren.SetBackgroundTexture(tex)
        ren.SetTexturedBackground(True)
        t = self.editor.timings
        parts = " · ".join(f"{k} {t[k] * 1e3:.0f} ms" for k in ("bake", "render", "total") if k in t)
        what = {"bake": "geometry re-baked", "materials": "new small-scale BRDFs", "render": "re-rendered"}.get(
            t.get("redone"), "")
        coarse = " (coarse preview)" if self._coarse else ""
        design = self.editor.family or "mesh tile"
        self.frame_text.SetText(2, f"{design}: {what}{coarse}\n{parts}")

    def say(self, text, error=False):
        """A one-line message under the frame (errors in red)."""
        self.status = text
        self.message.SetText(0, text)
        self.message.GetTextProperty().SetColor((1.0, 0.35, 0.3) if error else (0.85, 0.95, 0.85))

    # ---------------------------------------------------------------- the panel
    def _tabs(self):
        """The panel's tabs: the editor's groups, then the window's own "view" (slice angle, brush)."""
        groups = list(controls_of(self.editor.parameters()))
        return groups + ["view"]

    def _view_controls(self):
        out = [Control("view.theta_i", "slice theta_i", 0.0, 85.0, "real", help="the polar slice's incidence, degrees")]
        if self.editor.family == "heightfield":
            out += [Control("view.brush_radius", "brush radius", 0.02, 0.5, "real", help="tile units"),
                    Control("view.brush_strength", "brush strength", 0.01, 1.0, "real",
                            help="height added (raise), taken (lower) or blend to the blur (smooth) a dab")]
        return out

    # Rows of the panel, in fractions of its height: the tabs on top, the toggles and the key help at the bottom.
    TAB_ROW = (0.88, 1.0)
    TOGGLE_ROW = (0.11, 0.21)

    def buttons(self):
        """The panel's clickable cells: [(label, action, (u0, v0, u1, v1) in panel fractions)]; each row's cells
        as wide as their labels need, so that long names do not run into each other."""
        rows = [([(t, ("tab", t)) for t in self._tabs()], self.TAB_ROW, 1.0),
                ([(f"looking inside: {'on' if self.inside else 'off'} (i)", ("inside", None))]
                 + ([(f"brush: {self.brush['mode']} (m; drag on the tile)", ("brush", None))]
                    if self.editor.family == "heightfield" else []), self.TOGGLE_ROW, 0.9)]
        out = []
        for cells, (v0, v1), span in rows:
            weights = np.array([len(label) + 4.0 for label, _ in cells])
            edges = np.concatenate([[0.0], np.cumsum(weights) / weights.sum() * span])
            out += [(label, action, (edges[i], v0, edges[i + 1], v1)) for i, (label, action) in enumerate(cells)]
        return out

    def _setup_panel(self):
        ren = self._use("panel")
        ren.set_background("#1c1f24")
        self._tab_actors = []
        self.help_text = self.plotter.add_text("", position=(0.01, 0.02), viewport=True, font_size=8,
                                               color="#9aa4b0", name="help_text")
        self._build_tab()

    def _draw_buttons(self):
        ren = self.renderers["panel"]
        for a in self._tab_actors:
            ren.RemoveActor(a)
        self._tab_actors = []
        self._use("panel")
        for i, (label, (kind, arg), (u0, v0, u1, v1)) in enumerate(self.buttons()):
            active = (kind == "tab" and arg == self.tab) or (kind == "inside" and self.inside) or (
                kind == "brush" and self.brush["mode"] != "off")
            a = self.plotter.add_text(label, position=((u0 + u1) / 2, (v0 + v1) / 2), viewport=True, font_size=9,
                                      color="white" if active else "#8a939e", name=f"button{i}")
            prop = a.GetTextProperty()
            prop.SetJustificationToCentered()
            prop.SetVerticalJustificationToCentered()
            prop.SetBold(active)
            self._tab_actors.append(a)

    def _build_tab(self):
        """The sliders of the current tab (made again when the tab or the parameters it shows change)."""
        for w in self.sliders.values():
            w.Off()
            if w in self.plotter.widgets.slider_widgets:
                self.plotter.widgets.slider_widgets.remove(w)
        self.sliders = {}
        tabs = self._tabs()
        if self.tab not in tabs:
            self.tab = tabs[0]
        groups = controls_of(self.editor.parameters())
        controls = self._view_controls() if self.tab == "view" else groups[self.tab]
        self._controls = {c.key: c for c in controls}
        self._param_names = [p.name for p in self.editor.parameters()]
        self._draw_buttons()
        # slider cells in window fractions: the panel's rows under the tab row
        px0, py0, px1, py1 = self.renderers["panel"].GetViewport()
        top = py0 + (py1 - py0) * self.TAB_ROW[0]
        bottom = py0 + (py1 - py0) * self.TOGGLE_ROW[1]
        rows = max(4, -(-len(controls) // COLUMNS))
        row_h = (top - bottom) / rows
        cell_w = (px1 - px0) / COLUMNS
        self._use("panel")
        for i, c in enumerate(controls):
            r, col = divmod(i, COLUMNS)
            y = top - (r + 0.3) * row_h
            xa, xb = px0 + col * cell_w + 0.12 * cell_w, px0 + (col + 1) * cell_w - 0.06 * cell_w
            self._updating = True  # pyvista calls the callback once when the slider is made: not an edit
            w = self.plotter.add_slider_widget(
                lambda v, key=c.key: self.on_slide(key, v), [c.lo, c.hi], value=self._position(c), title=c.label,
                style="modern", interaction_event="always", title_height=0.05, slider_width=0.04, tube_width=0.006)
            self._updating = False
            rep = w.GetRepresentation()
            # pyvista scales the points by the viewport's size without moving them into it: place them here,
            # in window fractions
            rep.GetPoint1Coordinate().SetValue(xa, y)
            rep.GetPoint2Coordinate().SetValue(xb, y)
            rep.ShowSliderLabelOff()  # the value goes into the title, in the parameter's own units
            rep.SetTitleHeight(0.05)
            rep.SetEndCapLength(0.005)
            w.AddObserver("EndInteractionEvent", lambda *_, key=c.key: self.on_release(key))
            self.sliders[c.key] = w
        self._sync_sliders()
        self.help_text.SetInput(self._help_line())

    def _help_line(self):
        keys = "keys: u undo · r redo · s save · p screenshot · g next tab · i inside"
        if self.editor.family == "heightfield":
            keys += " · m brush"
        return keys

    def _position(self, c: Control) -> float:
        if c.key == "view.theta_i":
            return self.theta_i
        if c.key.startswith("view.brush_"):
            return self.brush[c.key[11:]]
        return to_slider(c, self.editor.get(c.name))

    def _value(self, c: Control):
        if c.key.startswith("view."):
            return self._position(c)
        return self.editor.get(c.name)

    def _sync_sliders(self):
        """Sliders and their titles from the editor's values (after an undo, a snap to an int, ...)."""
        for key, w in self.sliders.items():
            c = self._controls[key]
            rep = w.GetRepresentation()
            rep.SetValue(self._position(c))
            value = self._value(c)
            text = f"{value:.3g}" if key.startswith("view.") else shown(c, value)
            rep.SetTitleText(f"{c.label}  {text}")

    # ---------------------------------------------------------------- edits
    def on_slide(self, key, position):
        """A slider moved (pyvista's callback, every step of a drag): a coarse edit and a new frame. A choice is
        only shown while it moves and applied when let go: a new material kind brings other sliders, which must
        not replace the one being dragged."""
        if self._updating:
            return
        c = self._controls[key]
        if key.startswith("view."):
            self._set_view(key, position)
        elif c.scale in ("choice", "bool"):
            value = from_slider(c, position, None)
            self.sliders[key].GetRepresentation().SetTitleText(f"{c.label}  {value} (let go to apply)")
        else:
            self._edit(c, position)

    def on_release(self, key):
        """The slider was let go: the full-quality bake replaces the coarse one; the drag is one undo step."""
        c = self._controls.get(key)
        if c is None or key.startswith("view."):
            return
        if c.scale in ("choice", "bool"):
            self._edit(c, self.sliders[key].GetRepresentation().GetValue())
        self.finish_edit()

    def _edit(self, c: Control, position):
        value = from_slider(c, position, self.editor.get(c.name))
        self.editor.begin_step()
        try:
            redo = self.editor.set(c.name, value, coarse=True)
        except ValueError as exc:
            self.say(f"error: {exc}", error=True)
            self._sync_sliders()
            self.plotter.render()
            return
        if redo == "none":
            self._sync_sliders()  # an int snapped back to where it was
            return
        self._coarse = True  # a coarse bake or frame, until the release refines it
        self.say(f"{c.name} = {shown(c, self.editor.get(c.name))}")
        self.refresh(redo)

    def finish_edit(self):
        """The end of a drag or a brush stroke: the full bake if the last was coarse, one undo step for all."""
        refined = self.editor.refine()
        self._coarse = False
        self.editor.end_step()
        self.refresh(self.editor.timings.get("redone", "bake") if refined else "none", frame=refined)

    def _set_view(self, key, position):
        if key == "view.theta_i":
            self.theta_i = float(position)
            if self.inside:
                self._draw_polar()
        else:
            self.brush[key[11:]] = float(position)
        self._sync_sliders()
        self.plotter.render()

    def refresh(self, redo, frame=True):
        """Show what `redo` changed: the frame, the tile ("bake"), the inside views, the sliders."""
        if frame:
            self._show_frame()
        if redo == "bake":
            self._draw_tile()
        if [p.name for p in self.editor.parameters()] != self._param_names:
            self._build_tab()  # a material's kind changed: other parameters
        else:
            self._sync_sliders()
        if not self.editor.in_step:  # not in the middle of a drag or a stroke: the truth of what is shown
            self._request_truth()
        if self.inside:
            self._draw_inside(redo)
        self.plotter.render()

    # ---------------------------------------------------------------- commands
    def undo(self):
        if self.editor.undo():
            self.say("undone")
            self.refresh("bake")
        else:
            self.say("nothing to undo")
            self.plotter.render()

    def redo(self):
        if self.editor.redo():
            self.say("redone")
            self.refresh("bake")
        else:
            self.say("nothing to redo")
            self.plotter.render()

    def save(self):
        if self.output is None:
            self.say("no file to save to: start the editor with -o design.toml", error=True)
        else:
            try:
                self.editor.save(self.output)
                self.say(f"saved {self.output} (warp-biscale render {self.output})")
            except (ValueError, OSError) as exc:
                self.say(f"error: {exc}", error=True)
        self.plotter.render()

    def snapshot(self):
        """The whole window as the next free NAME-NNN.png (NAME: the -o file's, else "edit")."""
        stem = os.path.splitext(self.output)[0] if self.output else "edit"
        while True:
            self.shots += 1
            path = f"{stem}-{self.shots:03d}.png"
            if not os.path.exists(path):
                break
        self.screenshot(path)
        self.say(f"wrote {path}")
        self.plotter.render()
        return path

    def next_tab(self):
        tabs = self._tabs()
        self.select_tab(tabs[(tabs.index(self.tab) + 1) % len(tabs)])

    def select_tab(self, tab):
        if tab not in self._tabs():
            raise ValueError(f"no tab {tab!r}; the tabs are {', '.join(self._tabs())}")
        self.tab = tab
        self._build_tab()
        self.plotter.render()

    def toggle_inside(self):
        self.inside = not self.inside
        self._layout()
        self._draw_buttons()
        if self.inside:
            self._request_truth()
            self._draw_inside("bake")
        self.plotter.render()

    def cycle_brush(self):
        if self.editor.family != "heightfield":
            self.say("only a height field can be painted", error=True)
        else:
            modes = BRUSH_MODES
            self.brush["mode"] = modes[(modes.index(self.brush["mode"]) + 1) % len(modes)]
            self.say(f"brush: {self.brush['mode']}" + ("" if self.brush["mode"] == "off" else
                                                       " (left drag on the tile paints)"))
            self._draw_buttons()
        self.plotter.render()

    # ---------------------------------------------------------------- mouse and keys
    def _setup_events(self):
        iren = self.plotter.iren
        if iren is None:
            return
        it = iren.interactor
        # Priority over the interactor style (0) and under the slider widgets (0.5): a press on a slider stays
        # the slider's; a paint stroke or a tab click never reaches the camera.
        self._observers = [
            it.AddObserver("LeftButtonPressEvent", self._on_press, 0.4),
            it.AddObserver("MouseMoveEvent", self._on_move, 0.4),
            it.AddObserver("LeftButtonReleaseEvent", self._on_release_mouse, 0.4),
            it.AddObserver("KeyPressEvent", self._on_key, 1.0),
            it.AddObserver("CharEvent", self._on_char, 1.0),
        ]

    def _renderer_at(self, x, y):
        for name, ren in self.renderers.items():
            if ren.GetDraw() and ren.IsInViewport(x, y):
                return name
        return None

    def _on_press(self, obj, event):
        x, y = obj.GetEventPosition()
        where = self._renderer_at(x, y)
        tag = self._observers[0]
        if where == "panel":
            self._click_panel(x, y)
            _abort(obj, tag)
        elif where == "tile" and self.brush["mode"] != "off" and self.editor.family == "heightfield":
            point = self.pick_tile(x, y)
            if point is not None:
                self._painting = True
                self.editor.begin_step()
                self._stroke = None
                self.dab(point)
                _abort(obj, tag)
        elif where in ("frame", "polar"):
            _abort(obj, tag)  # nothing to turn there: the frame is an image, the slice a plot

    def _on_move(self, obj, event):
        if not self._painting:
            return
        x, y = obj.GetEventPosition()
        point = self.pick_tile(x, y)
        if point is not None:
            self.dab(point)
        _abort(obj, self._observers[1])

    def _on_release_mouse(self, obj, event):
        if not self._painting:
            return
        self._painting = False
        self._stroke = None
        self.finish_edit()
        _abort(obj, self._observers[2])

    def _click_panel(self, x, y):
        x0, y0, x1, y1 = self.renderers["panel"].GetViewport()
        W, H = self.plotter.render_window.GetSize()
        u, v = (x / W - x0) / (x1 - x0), (y / H - y0) / (y1 - y0)
        for _, (kind, arg), (u0, v0, u1, v1) in self.buttons():
            if u0 <= u <= u1 and v0 <= v <= v1:
                if kind == "tab":
                    self.select_tab(arg)
                elif kind == "inside":
                    self.toggle_inside()
                else:
                    self.cycle_brush()
                return

    KEYS = {"u": "undo", "r": "redo", "y": "redo", "s": "save", "p": "snapshot", "i": "toggle_inside",
            "g": "next_tab", "m": "cycle_brush"}

    def _on_key(self, obj, event):
        sym = (obj.GetKeySym() or "").lower()
        ctrl, shift = obj.GetControlKey(), obj.GetShiftKey()
        if ctrl and sym == "z":
            action = "redo" if shift else "undo"
        elif ctrl and sym in ("y", "s"):
            action = self.KEYS[sym]
        elif not ctrl and sym in self.KEYS:
            action = self.KEYS[sym]
        else:
            return
        _abort(obj, self._observers[3])
        getattr(self, action)()

    def _on_char(self, obj, event):
        # VTK's own keys (r: reset the camera, s: surfaces, p: pick, u: user event) would run too
        if (obj.GetKeySym() or "").lower() in self.KEYS or obj.GetControlKey():
            _abort(obj, self._observers[4])

    # ---------------------------------------------------------------- the tile and painting
    def _setup_tile(self):
        ren = self._use("tile")
        ren.set_background("#30343a", top="#8a9aab")
        self.tile_text = self.plotter.add_text("", position="upper_left", font_size=9, color="white", shadow=True,
                                               name="tile_text")
        self._tile_actor = None
        self._tile_camera_set = False

    def _draw_tile(self):
        tile = self.editor.tile
        self._use("tile")
        poly = tile_polydata(tile, self.editor.materials)
        self._tile_actor = self.plotter.add_mesh(poly, scalars="rgb", rgb=True, smooth_shading=False, name="tile",
                                                 show_scalar_bar=False, reset_camera=False)
        ids = sorted(set(tile.material_ids.tolist()))
        label = f"tile: {self.editor.family or tile.name}, {len(tile.faces)} triangles, materials {ids}"
        self.tile_text.SetText(2, label)
        if not self._tile_camera_set:  # the first tile sets the view; later ones keep what the user made of it
            ren = self.renderers["tile"]
            c = ren.camera
            size = 3 * max(tile.period)
            steep = self.editor.family == "heightfield"  # painting wants to see the field from above
            c.SetFocalPoint(0.0, 0.0, float(np.mean(tile.z_range)))
            c.SetPosition(0.5 * size, -0.9 * size, (2.2 if steep else 1.2) * size)
            c.SetViewUp(0.0, 0.0, 1.0)
            c.SetViewAngle(30.0)
            ren.ResetCamera()
            ren.camera.Zoom(1.3 if steep else 1.05)
            ren.camera.is_set = True
            self._tile_camera_set = True

    def pick_tile(self, x, y):
        """The tile point under display pixel (x, y) (VTK's: from the bottom left), or None."""
        from vtkmodules.vtkRenderingCore import vtkCellPicker  # (`import vtk` would load all of VTK: a second)

        if self._tile_actor is None:
            return None
        if self._picker is None:
            self._picker = vtkCellPicker()
            self._picker.SetTolerance(1e-4)
            self._picker.PickFromListOn()
        self._picker.InitializePickList()
        self._picker.AddPickList(self._tile_actor)
        if not self._picker.Pick(x, y, 0.0, self.renderers["tile"]):
            return None
        return np.array(self._picker.GetPickPosition())

    def tile_coordinates(self, point):
        """A world point on the drawn tile (3 × 3 periods centred on the origin) → (x, y) in [0, 1]² of the
        tile, as `Editor.paint` takes them."""
        px, py = self.editor.tile.period
        return (float(np.clip(((point[0] + px / 2) % px) / px, 0, 1)),
                float(np.clip(((point[1] + py / 2) % py) / py, 0, 1)))

    def dab(self, point):
        """One brush dab at a picked tile point (skipped if too close to the last one of the stroke)."""
        x, y = self.tile_coordinates(point)
        r, s, mode = self.brush["radius"], self.brush["strength"], self.brush["mode"]
        if self._stroke is not None:
            dx, dy = abs(x - self._stroke[0]), abs(y - self._stroke[1])
            if math.hypot(min(dx, 1 - dx), min(dy, 1 - dy)) < r / 3:
                return False  # dabs a third of the radius apart: an even stroke, not a bake per mouse pixel
        self._stroke = (x, y)
        try:
            if mode == "smooth":
                self.editor.smooth(x, y, r, min(s, 1.0), coarse=True)
            else:
                self.editor.paint(x, y, r, s if mode == "raise" else -s, coarse=True)
        except ValueError as exc:
            self.say(f"error: {exc}", error=True)
            return False
        self._coarse = True
        self.say(f"{mode} at ({x:.2f}, {y:.2f})")
        self.refresh("bake")
        return True

    # ---------------------------------------------------------------- looking inside
    def _setup_inside(self):
        pv = self.pv
        ren = self._use("ndf")
        ren.set_background("#101418")
        # the upper hemisphere: where the normals of a surface seen from above lie
        self.plotter.add_mesh(pv.Sphere(radius=1.0, theta_resolution=36, phi_resolution=10, end_phi=90),
                              color="#5a6470", style="wireframe", opacity=0.35, name="unit_sphere",
                              reset_camera=False)
        circle = pv.Circle(radius=1.0, resolution=72)
        self.plotter.add_mesh(circle.extract_feature_edges(boundary_edges=True, feature_edges=False,
                                                           manifold_edges=False, non_manifold_edges=False),
                              color="#aab4c0", line_width=2, name="horizon", reset_camera=False)
        self.ndf_text = self.plotter.add_text("", position="upper_left", font_size=8, color="white", shadow=True,
                                              name="ndf_text")
        c = ren.camera
        c.SetFocalPoint(0.0, 0.0, 0.45)
        c.SetPosition(*(np.array([0.5, -0.7, 0.5]) * 4.6 + [0, 0, 0.45]))
        c.SetViewUp(0.0, 0.0, 1.0)
        c.SetViewAngle(30.0)
        c.is_set = True

        ren = self._use("polar")
        ren.set_background("#101418")
        t = np.radians(np.linspace(-90, 90, 91))
        arc = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], 1)
        self.plotter.add_mesh(pv.lines_from_points(arc), color="#5a6470", line_width=1, name="polar_arc",
                              reset_camera=False)
        self.plotter.add_mesh(pv.Line((-1.05, 0, 0), (1.05, 0, 0)), color="#aab4c0", line_width=2,
                              name="polar_ground", reset_camera=False)
        self.polar_text = self.plotter.add_text("", position="upper_left", font_size=8, color="white", shadow=True,
                                                name="polar_text")
        c = ren.camera
        c.ParallelProjectionOn()
        c.SetFocalPoint(0.0, 0.0, 0.45)
        c.SetPosition(0.0, -10.0, 0.45)
        c.SetViewUp(0.0, 0.0, 1.0)
        c.SetParallelScale(0.62)
        c.is_set = True

    def _draw_inside(self, redo):
        if redo == "bake":
            self._draw_ndf()
        self._draw_polar()

    def _draw_ndf(self):
        pv = self.pv
        eff = self.editor.effective
        self._use("ndf")
        bv = eff.bvndf
        if bv is not None and len(bv.normal):
            pts = pv.PolyData(np.asarray(bv.normal, np.float64))
            dens = np.asarray(bv.ndf, np.float64)
            pts["log10 Γ"] = np.log10(np.maximum(dens, dens.max() * 1e-6))
            self.plotter.add_mesh(pts, scalars="log10 Γ", cmap="viridis", point_size=10 if len(pts.points) < 200 else 4,
                                  render_points_as_spheres=True, show_scalar_bar=False, name="ndf_points",
                                  reset_camera=False)
        ax = np.asarray(eff.lobes.axes, np.float64)
        eta = np.asarray(eff.lobes.sharpness, np.float64)
        # Each lobe an arrow standing on the sphere at its axis, out of the cloud of normals; η spans 1 to 10^6,
        # so its length is by log η.
        length = 0.1 + 0.1 * np.log10(1.0 + eta)
        arrows = pv.PolyData(ax.copy())
        arrows["v"] = ax * length[:, None]
        glyphs = arrows.glyph(orient="v", scale="v", factor=1.0, geom=pv.Arrow(tip_length=0.3, tip_radius=0.09,
                                                                                shaft_radius=0.035))
        self.plotter.add_mesh(glyphs, color=ORANGE, name="lobes", reset_camera=False)
        nb = 0 if bv is None else len(bv.normal)
        # (VTK's font has no Greek letters: the labels spell them)
        self.ndf_text.SetText(2, f"normal distribution: {nb} normal bins (colour: log density)\n{len(eta)} SG lobes: "
                                 "arrows at their axes, length 0.1 (1 + log10(1 + sharpness))")

    def _request_truth(self):
        if self.truth is not None and self.inside:
            self.truth.request(design_key(self.editor.tile, self.editor.materials), self.editor.tile,
                               self.editor.materials)

    def current_truth(self):
        """(GroundTruth or error text or None, seconds) of the current design, if it has arrived."""
        if self.truth is None:
            return None, 0.0
        return self.truth.cache.get(design_key(self.editor.tile, self.editor.materials), (None, 0.0))

    def poll(self, timeout: float = 0.0) -> bool:
        """Show a ground truth that has arrived from the worker (a timer calls this in a live window)."""
        if self.truth is None or not self.truth.poll(timeout):
            return False
        if self.inside:
            self._draw_polar()
            self.plotter.render()
        return True

    def wait_truth(self, timeout: float = 120.0) -> bool:
        """Wait until the current design's ground truth is here (tests, scripts) → whether it came."""
        end = time.perf_counter() + timeout
        while self.current_truth()[0] is None and time.perf_counter() < end:
            self.poll(timeout=min(1.0, max(0.0, end - time.perf_counter())))
        return self.current_truth()[0] is not None

    def slice(self, n: int = 121):
        """The polar slice: θo (degrees, negative on the side away from ωi), f̄ of the bake and of the ground
        truth (None until it is here), mean of RGB, for ωi at `theta_i` in the x-z plane."""
        to = np.radians(np.linspace(-88, 88, n))
        ti = math.radians(self.theta_i)
        wi = np.tile([math.sin(ti), 0.0, math.cos(ti)], (n, 1))
        wo = np.stack([np.sin(to), np.zeros(n), np.cos(to)], 1)
        ours = self.editor.effective.eval(wi, wo).mean(axis=1)
        gt, _ = self.current_truth()
        truth = gt.eval(wi, wo).mean(axis=1) if gt is not None and not isinstance(gt, str) else None
        return np.degrees(to), ours, truth

    def _draw_polar(self):
        from .effective import compare

        pv = self.pv
        self._use("polar")
        theta, ours, truth = self.slice()
        peak = max(float(ours.max()), float(truth.max()) if truth is not None else 0.0, 1e-12)
        t = np.radians(theta)

        def curve(f):
            r = f / peak
            return pv.lines_from_points(np.stack([r * np.sin(t), np.zeros_like(t), r * np.cos(t)], 1))

        self.plotter.add_mesh(curve(ours), color=ORANGE, line_width=3, name="polar_ours", reset_camera=False)
        if truth is not None:
            self.plotter.add_mesh(curve(truth), color=CYAN, line_width=2, name="polar_truth", reset_camera=False)
        else:
            self.plotter.remove_actor("polar_truth", render=False)
        ti = math.radians(self.theta_i)
        self.plotter.add_mesh(pv.Line((0, 0, 0), (1.05 * math.sin(ti), 0, 1.05 * math.cos(ti))), color="yellow",
                              line_width=2, name="polar_wi", reset_camera=False)
        gt, seconds = self.current_truth()
        t = self.editor.timings
        bake = f"bake {t['bake'] * 1e3:.0f} ms" if "bake" in t else ""
        if isinstance(gt, str):
            err = f"ground truth failed: {gt}"
        elif gt is None:
            err = "PSNR: ground truth on its way…" if self.truth is not None else "PSNR: no ground truth"
        else:
            c = compare(self.editor.effective, gt)
            err = (f"PSNR {c['psnr']:.1f} dB against the ground truth "
                   f"(2^{int(math.log2(gt.facets))} facets, K = {gt.directions}, {seconds:.1f} s)")
        self.polar_text.SetText(2, f"effective BRDF in the plane of incidence (yellow: theta_i = {self.theta_i:.0f}°): "
                                   f"bake (orange), ground truth (cyan); radius: f / {peak:.3g}\n{err} · {bake}")

    # ---------------------------------------------------------------- output
    def screenshot(self, path=None) -> np.ndarray:
        """Draw the window and write it as a PNG (if `path`) → (H, W, 3) uint8."""
        self.plotter.render()
        img = np.ascontiguousarray(self.plotter.screenshot(None, return_img=True)[..., :3])
        if path is not None:
            from PIL import Image

            check_output(os.fspath(path))
            with atomic_path(path) as tmp:
                Image.fromarray(img, "RGB").save(tmp, format="PNG")
        return img

    def show(self):
        """Open the window (blocks until it is closed); a timer brings the ground truth in when it is ready."""
        iren = self.plotter.iren
        if iren is not None and self.truth is not None:
            iren.interactor.AddObserver("TimerEvent", lambda *_: self.poll())
            if not iren.initialized:
                iren.initialize()  # (a timer needs the event loop's context, made here)
            iren.create_timer(300, repeating=True)
        self.plotter.show()

    def close(self):
        if self.truth is not None:
            self.truth.close()
            self.truth = None
        self.plotter.close()


def open_editor(editor, off_screen=False, window_size=None, output=None, truth=True) -> EditorWindow:
    """The editor's window around `editor` (an `editor.Editor`), drawn once; `show()` opens it. `output`: where
    's' saves the design; `truth`: compute the ground truth in the background for the error shown."""
    return EditorWindow(editor, off_screen=off_screen, window_size=window_size, output=output, truth=truth)


def edit(target, output=None, backend="auto", size=(640, 480), screenshot=None, inside=False):
    """`warp-biscale edit`: open the editor on a tile family, an image, a mesh file or a design (.toml); with
    `screenshot`, draw offscreen, write that PNG and return its pixels instead of opening a window."""
    from .editor import Editor, check_target

    if output is not None:
        check_output(os.fspath(output), (".toml",), "--output")
    check_target(target)  # (a bad target is a bad argument, said before a missing display)
    if screenshot is None and not _has_display():
        raise RuntimeError("no display to open a window on (DISPLAY is not set): use --screenshot out.png to "
                           "draw offscreen, or run under X (e.g. xvfb-run)")
    if screenshot is not None:
        _ensure_offscreen_gl()
    spec = os.fspath(target)
    if spec.lower().endswith(".toml"):
        ed = Editor.load(spec, backend=backend)
    else:
        ed = Editor(spec, backend=backend, width=int(size[0]), height=int(size[1]))
    w = open_editor(ed, off_screen=screenshot is not None, output=output, truth=screenshot is None or inside)
    try:
        if screenshot is not None:
            if inside:
                w.toggle_inside()
                w.wait_truth()
            return w.screenshot(screenshot)
        w.show()
        return None
    finally:
        w.close()
