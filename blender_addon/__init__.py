"""skyloc's Blender simulator, packaged as a Blender extension (see blender_manifest.toml).

Importing this package does not import bpy: the bpy-free subpackages (``blender_addon.core``,
``blender_addon.terrain``) are used without Blender.  Blender calls :func:`register` and
:func:`unregister`; they add the properties (``Scene.skyloc``), the ``SKYLOC_OT_*`` operators
and the "Skyloc" tab of the 3D View sidebar.
"""


def register() -> None:
    """Register properties, operators and panels (called by Blender when the extension is enabled)."""
    from . import ops, props, ui, ui_descent

    props.register()
    ops.register()
    ui.register()
    ui_descent.register()       # the descent panel and its operators (issue 14)


def unregister() -> None:
    """Remove everything :func:`register` added, in reverse order."""
    from . import ops, props, ui, ui_descent

    ui_descent.unregister()
    ui.unregister()
    ops.unregister()
    props.unregister()
