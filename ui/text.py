"""Text that fits the sidebar: labels measured and wrapped at the width Blender gives them.

Blender cuts a label that does not fit ("Rotation Preci…"). Settings' names are short
enough for the sidebar's default width (:data:`SPLIT_LABEL`, :data:`CHECKBOX_TEXT`,
:data:`MENU_TEXT`: ``tests/blender/test_bl_panels.py`` measures every drawn name
against them); hints and statuses are wrapped here at the sidebar's width as it is
(:func:`note`), measured with Blender's own font (``blf``) at the user's UI scale;
a warning that needs an action is one line with its button (:func:`warning`).

The widths are pixels at UI scale 1, measured on Blender 4.3 (``make docs-images``).
"""

from __future__ import annotations

import blf

#: Blender's default width of the 3D view's sidebar: a panel drawn without a region
#: (the tests) is measured at it.
SIDEBAR_WIDTH = 280
#: What a label line leaves of the sidebar's width: the category tabs and the panel's
#: margins; a box's own margins; an icon.
EDGES, BOX, ICON = 58, 12, 22
#: The widest name that shows whole at the default width: in the label column of a
#: setting (a split layout gives it 40 %; a box a little less: "Recovery Rate", "Max
#: Distance"), beside a checkbox ("Clear in Viewport", in a box), and a choice's name in
#: its menu button.
SPLIT_LABEL, SPLIT_LABEL_BOX, CHECKBOX_TEXT, MENU_TEXT = 75, 71, 91, 95
#: The room a button takes beyond its text (its rounded edges, the text's insets).
BUTTON_PADDING = 16


def ui_scale(context) -> float:
    """The UI's scale (pixels per pixel at scale 1); 1 without a window (background)."""
    return context.preferences.system.ui_scale or 1.0


def text_width(context, text: str) -> float:
    """Pixels ``text`` takes in a label, in Blender's UI font at the UI scale."""
    blf.size(0, context.preferences.ui_styles[0].widget.points * ui_scale(context))
    return blf.dimensions(0, text)[0]


def region_width(context) -> float:
    region = getattr(context, "region", None)
    width = getattr(region, "width", 0) or 0
    return width if width > 1 else SIDEBAR_WIDTH * ui_scale(context)


def line_width(context, box=False, icon=True) -> float:
    """Pixels a label line has in the sidebar as it is now (in a ``box``, after an
    ``icon``)."""
    s = ui_scale(context)
    return region_width(context) - s * (EDGES + (BOX if box else 0) + (ICON if icon else 0))


def wrap(context, text: str, width: float) -> list[str]:
    """``text`` in lines of at most ``width`` pixels, broken between words (a word wider
    than the line is a line of its own)."""
    lines, cur = [], ""
    for word in text.split():
        cand = f"{cur} {word}" if cur else word
        if cur and text_width(context, cand) > width:
            lines.append(cur)
            cur = word
        else:
            cur = cand
    if cur:
        lines.append(cur)
    return lines


def note(layout, context, text: str, icon="INFO", box=False) -> None:
    """``text`` as labels wrapped to the sidebar's width, ``icon`` before the first line
    (the next ones indented as far). ``box``: ``layout`` is (in) a box."""
    width = line_width(context, box=box, icon=icon != "NONE")
    col = layout.column(align=True)
    for i, line in enumerate(wrap(context, text, width)):
        col.label(text=line, icon=icon if i == 0 or icon == "NONE" else "BLANK1")


def warning(layout, context, text: str, operator: str, button: str, icon="ERROR"):
    """One line: what is wrong (``text``, after ``icon``) and, beside it, the button that
    fixes it (``operator``, its text ``button``). Returns the button's properties."""
    s = ui_scale(context)
    need = text_width(context, text) + s * (ICON + 8)
    row = layout.row()
    split = row.split(factor=min(0.6, max(0.3, need / max(1.0, line_width(context, icon=False)))))
    split.label(text=text, icon=icon)
    return split.operator(operator, text=button)
