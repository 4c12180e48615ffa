"""Rendering hook of :class:`filters.wrapper.SafetyFilterWrapper`: it draws the
first-step halfspace boundaries in the environment's frames (matplotlib on first use)."""

from __future__ import annotations

from typing import Any


class RenderHookMixin:
    """The wrapper's render hook (mixed into :class:`filters.wrapper.SafetyFilterWrapper`,
    whose attributes it uses)."""

    def _install_render_hook(self) -> None:
        hooks = self._unwrapped.render_hooks
        if self._draw_halfspaces in hooks:  # bound methods of this wrapper compare equal
            hooks.remove(self._draw_halfspaces)
        if self.draw_halfspaces and self.risk != "none":
            hooks.append(self._draw_halfspaces)

    def _draw_halfspaces(self, ax: Any) -> None:
        """Draw the first-step halfspace boundary of every obstacle (one line collection)."""
        halfspaces = self._last_halfspaces
        if halfspaces is not None:  # (no collection when every row is off: keep the last)
            from filters.plotting import draw_halfspaces

            self._halfspace_lines = draw_halfspaces(
                ax, halfspaces.normals[:, 0], halfspaces.offsets[:, 0],
                reuse=self._halfspace_lines) or self._halfspace_lines
