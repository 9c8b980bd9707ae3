"""stablemofusion for Blender: text to motion on the selected armature.

Install: Edit > Preferences > Add-ons > Install..., pick a zip of this folder (or copy the folder into
Blender's scripts/addons), enable "Animation: stablemofusion". The panel is in the 3D view's sidebar (N),
tab "Motion". See docs/character.md.
"""

bl_info = {
    "name": "stablemofusion",
    "author": "stablemofusion contributors",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "View3D > Sidebar > Motion",
    "description": "Generate a human motion from text and apply it to the selected armature (Mixamo, "
                   "Bandai-Namco or our own joint names) or to a new skeleton",
    "category": "Animation",
}

import textwrap

import bpy  # noqa: E402
from bpy.props import EnumProperty, FloatProperty, IntProperty, StringProperty  # noqa: E402

from . import motion  # noqa: E402


class SMF_PG_settings(bpy.types.PropertyGroup):
    prompt: StringProperty(name="Prompt", default="a person walks forward")
    seconds: FloatProperty(name="Seconds", default=0.0, min=0.0, max=9.8,
                           description="0: the length is predicted from the prompt")
    seed: IntProperty(name="Seed", default=0, min=0)
    backend: EnumProperty(name="Run", items=[
        ("AUTO", "Auto", "in Blender when the stablemofusion runtime is importable, else the server"),
        ("LOCAL", "In Blender", "the stablemofusion runtime (ONNX Runtime) in Blender's own Python: nothing else "
                                "running"),
        ("SERVER", "Server", "a running `smf serve`")], default="AUTO")
    server: StringProperty(name="Server", default="http://127.0.0.1:8000")


class SMF_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __name__

    packages: StringProperty(
        name="Python packages", subtype="DIR_PATH", default="",
        description="a site-packages folder holding the stablemofusion runtime (pip install stablemofusion, made "
                    "with Blender's Python version), for generating in Blender; empty: Blender's own")

    model: StringProperty(
        name="Model", subtype="DIR_PATH", default="",
        description="portable graphs of a model for generating in Blender (`smf export --onnx`, an adapted model "
                    "with --adapter); empty: the shipped model")

    def draw(self, context):
        self.layout.prop(self, "packages")
        self.layout.prop(self, "model")


class SMF_OT_generate(bpy.types.Operator):
    """Generate a motion from the prompt and apply it to the selected armature (or a new skeleton)"""

    bl_idname = "smf.generate_motion"
    bl_label = "Generate motion"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.smf
        if not s.prompt.strip():
            self.report({"ERROR"}, "the prompt is empty")
            return {"CANCELLED"}
        try:
            prefs = context.preferences.addons[__name__].preferences
            joints, fps, source = motion.generate_joints(s.prompt.strip(), s.seconds or None, s.seed, s.server, s.backend,
                                                         bpy.path.abspath(prefs.packages) if prefs.packages else "",
                                                         bpy.path.abspath(prefs.model) if prefs.model else "")
            motion.LAST_JOINTS = joints
            arm = context.active_object
            if arm is None or arm.type != "ARMATURE" or not arm.select_get():
                arm = motion.create_our_armature(joints)
            if context.mode != "OBJECT":
                bpy.ops.object.mode_set(mode="OBJECT")
            used = motion.apply_motion(arm, joints, fps, action_name=s.prompt.strip()[:60])
        except motion.MotionError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{len(joints)} frames at {fps:g} fps from {source} on {arm.name} (joint map {used})")
        for w in motion.LAST_WARNINGS:  # where the user looks: the status bar, and the panel until the next motion
            self.report({"WARNING"}, w)
        return {"FINISHED"}


class SMF_PT_panel(bpy.types.Panel):
    bl_label = "stablemofusion"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Motion"

    def draw(self, context):
        s = context.scene.smf
        col = self.layout.column()
        col.prop(s, "prompt")
        col.prop(s, "seconds")
        col.prop(s, "seed")
        col.prop(s, "backend")
        if s.backend != "LOCAL":
            col.prop(s, "server")
        col.operator(SMF_OT_generate.bl_idname, icon="ARMATURE_DATA")
        for w in motion.LAST_WARNINGS:
            box = col.box()
            for k, line in enumerate(textwrap.wrap(w, 40)):
                box.label(text=line, icon="ERROR" if k == 0 else "NONE")


CLASSES = (SMF_PG_settings, SMF_AP_preferences, SMF_OT_generate, SMF_PT_panel)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.smf = bpy.props.PointerProperty(type=SMF_PG_settings)


def unregister():
    del bpy.types.Scene.smf
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
