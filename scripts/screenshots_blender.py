"""Inside a Blender with a window (run by ``scripts/screenshots.py`` under Xvfb): take one set of UI screenshots.

    blender -p 0 0 W H SCENE.blend --python scripts/screenshots_blender.py -- OUT_DIR SHOT [--no-addon]

SHOT is ``panel`` (Output Properties with the Lowcam Camera panel: the Properties editor fills the window),
``compositor`` (the compositor with a Lowcam Camera node, then inside its group: ``compositor.png`` and
``group.png``), ``menu`` (the compositor's Add > Lowcam menu open) or ``match`` (the Match loop run on the
measurement set named after SHOT: ``match-before.png``, ``match-diagnosed.png``, ``match-added.png`` and
``match.json``). ``--no-addon`` disables the installed add-on first, so the same steps show the same window
without it. Writes OUT_DIR/<name>.png with Blender's own ImageMagick's ``import`` (or ``screen.screenshot``) and
then quits; a step that fails is written to OUT_DIR/error.txt.

The steps run from a timer, a fraction of a second apart, so that the window redraws between them.
"""
import shutil
import subprocess
import sys
import traceback
from pathlib import Path

import addon_utils
import bpy

MODULE = "bl_ext.user_default.lowcam"
ARGS = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
OUT = Path(ARGS[0]) if ARGS else Path("screenshots")
SHOT = ARGS[1] if len(ARGS) > 1 else "panel"
NO_ADDON = "--no-addon" in ARGS


def window():
    return bpy.context.window_manager.windows[0]


def biggest_area():
    return max(window().screen.areas, key=lambda a: a.width * a.height)


def region(area, kind="WINDOW"):
    return next(r for r in area.regions if r.type == kind)


def override(area=None, kind="WINDOW"):
    win = window()
    if area is None:
        return bpy.context.temp_override(window=win, screen=win.screen)
    return bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region(area, kind))


def full_screen(area):
    """The area alone in the window (header kept, top bar and status bar hidden); returns the area."""
    with override(area):
        bpy.ops.screen.screen_full_area(use_hide_panels=True)
    return biggest_area()


def shoot(name):
    """The X screen as OUT/<name>.png, grabbed by ImageMagick's ``import`` (under Xvfb Blender's own screenshot
    operator reads a black front buffer); Blender's operator where ``import`` is missing."""
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{name}.png"
    if shutil.which("import"):
        subprocess.run(["import", "-window", "root", str(path)], check=True, timeout=60)
    else:
        with override():
            bpy.ops.screen.screenshot(filepath=str(path), check_existing=False)


def output_properties():
    """Steps that make Output Properties fill the window; returns its area."""
    area = biggest_area()
    area.type = "PROPERTIES"
    yield 0.3
    area = full_screen(area)
    area.spaces.active.context = "OUTPUT"
    yield 1.0
    return area


def panel_steps():
    yield from output_properties()
    shoot("panel")


def compositor_area():
    scene = bpy.context.scene
    area = biggest_area()
    area.type = "NODE_EDITOR"
    area.ui_type = "CompositorNodeTree"
    if not NO_ADDON:
        with override(area):
            bpy.ops.lowcam.add_camera_node()
    if hasattr(scene, "use_nodes") and not scene.use_nodes:     # Blender 4.x: the compositor must be switched on
        scene.use_nodes = True
    return area


def frame_all(area):
    with override(area):
        bpy.ops.node.view_all()


def full_compositor():
    """Steps (waits in s) that make the compositor fill the window with every node in view; returns its area."""
    area = compositor_area()
    yield 0.3
    area = full_screen(area)
    yield 0.5
    frame_all(area)
    return area


def compositor_steps():
    area = yield from full_compositor()
    yield 0.8
    shoot("compositor")
    space = area.spaces.active
    node = next((n for n in space.edit_tree.nodes if n.bl_idname == "LowcamCameraNode"), None)
    if node is None:       # without the add-on there is no group to open: the same view again
        shoot("group")
        return
    space.path.append(node.node_tree, node=node)           # into the group: its stage nodes
    yield 1.0
    frame_all(area)
    yield 0.5
    frame_all(area)                                          # again, now that the group's nodes are drawn
    yield 0.8
    shoot("group")


def menu_steps():
    area = yield from full_compositor()
    yield 0.5
    win = window()
    win.cursor_warp(area.x + area.width // 3, area.y + area.height * 3 // 4)    # menus open at the cursor
    yield 0.3
    with override(area):
        if NO_ADDON:
            bpy.ops.wm.call_menu(name="NODE_MT_add")
        else:
            bpy.ops.wm.call_menu(name="NODE_MT_lowcam_add")
    yield 1.0
    shoot("menu")


def match_steps():
    """The Match loop run in this Blender: the Match panel alone in Output Properties (the tab's other panels are
    unregistered for the pictures) before, after Compare and Diagnose (the list filled) and after Add Best (the
    history plot). A probe timer every 0.05 s measures how long Blender's main thread waits between two calls
    (wall clock) and how much of that it spent working (its own CPU time) while the jobs run; the numbers go to
    OUT_DIR/match.json. ARGS: OUT_DIR match SET_DIR."""
    import importlib
    import json
    import time

    jobs = importlib.import_module(f"{MODULE}.addon.jobs")
    scene = bpy.context.scene
    m = scene.lowcam_match
    m.measurement_set, m.only = ARGS[2], "tone_curve,vignetting"
    others = [c for c in bpy.types.Panel.__subclasses__() if getattr(c, "bl_space_type", "") == "PROPERTIES"
              and getattr(c, "bl_context", "") == "output" and c.__name__ != "LOWCAM_PT_match_output"]
    for cls in sorted(others, key=lambda c: not getattr(c, "bl_parent_id", "")):   # sub-panels first
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
    area = yield from output_properties()
    shoot("match-before")
    gaps, last = [], [time.perf_counter(), time.thread_time()]

    def probe():
        now, cpu = time.perf_counter(), time.thread_time()
        # the gap, the main thread's CPU time in it, the step, when in the step (s)
        gaps.append((now - last[0], cpu - last[1], name, now - t0))
        last[:] = now, cpu
        return 0.05

    numbers = {}
    for name, op in (("compare", "match_compare"), ("diagnose", "match_diagnose"), ("add", "match_add")):
        with override(area):
            getattr(bpy.ops.lowcam, op)()              # with a window the operator returns at once
        t0 = time.perf_counter()
        last[:] = t0, time.thread_time()
        bpy.app.timers.register(probe, first_interval=0.05)
        while jobs.current() is not None:
            yield 0.25
        bpy.app.timers.unregister(probe)
        if m.job_error:
            raise RuntimeError(f"{name}: {m.job_error}")
        numbers[name] = {"error": m.error, "seconds": time.perf_counter() - t0}
        if name == "diagnose":
            numbers["candidates"] = [c.effect for c in m.candidates]
            yield 1.5                                  # the residual map's preview is drawn
            shoot("match-diagnosed")
    yield 2.0                                          # the history plot's preview is drawn
    shoot("match-added")
    # where the loop's child processes find their packages: the installed extension's wheels, nothing else
    argv, env = jobs.lowcam_command([])
    modules = "scipy, matplotlib, tifffile, tqdm, cv2, lowcam"
    where = subprocess.run([argv[0], "-c", f"import json, {modules}; print(json.dumps({{m.__name__: m.__file__ "
                            f"for m in ({modules})}}))"], env=env, capture_output=True, text=True, timeout=120)
    numbers["packages"] = json.loads(where.stdout) if where.returncode == 0 else where.stderr.strip()[-500:]
    numbers.update(versions=[[v.label, v.error] for v in m.versions], probe_calls=len(gaps),
                   longest_gap_s=max(g[0] for g in gaps), longest_gaps=sorted(gaps, reverse=True)[:6],
                   busiest_gap_cpu_s=max(g[1] for g in gaps))
    (OUT / "match.json").write_text(json.dumps(numbers, indent=1))


STEPS = {"panel": panel_steps, "compositor": compositor_steps, "menu": menu_steps, "match": match_steps}


def main():
    prefs = bpy.context.preferences
    prefs.use_preferences_save = False       # neither the disabled add-on nor these settings outlive this run
    prefs.view.show_tooltips = False         # no tooltip over the open menu
    if NO_ADDON:
        addon_utils.disable(MODULE, default_set=True)
    elif MODULE not in bpy.context.preferences.addons:
        raise RuntimeError(f"the add-on {MODULE} is not enabled in these user preferences")
    steps = STEPS[SHOT]()

    def tick():
        try:
            return next(steps)
        except StopIteration:
            bpy.ops.wm.quit_blender()
        except Exception:
            OUT.mkdir(parents=True, exist_ok=True)
            (OUT / "error.txt").write_text(traceback.format_exc())
            bpy.ops.wm.quit_blender()
        return None

    bpy.app.timers.register(tick, first_interval=1.5)


try:
    main()
except Exception:
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "error.txt").write_text(traceback.format_exc())
    bpy.ops.wm.quit_blender()
