"""Drawing the saddle, the ball and its trail (pygame; imported only when rendering).

Left: a perspective view of the spinning saddle in the laboratory. Right: the top view
(the saddle's rising x axis in red, falling y axis in blue) and the readings Ω and N/mg.
"""

from __future__ import annotations

import math
import os
from collections import deque

import numpy as np
from gymnasium.error import DependencyNotInstalled

from .. import kernels as K
from . import control_step as S
from .config import EnvConfig

WIDTH, HEIGHT = 600, 400
TRAIL = 150
BACKGROUND = (250, 250, 247)


class SaddleRenderer:
    """Draws the saddle, the ball and its trail with pygame, to an array or a window."""

    def __init__(self, config: EnvConfig, mode: str):
        try:
            import pygame
        except ImportError as exc:  # pragma: no cover - exercised only without pygame
            raise DependencyNotInstalled(
                'pygame is needed to render SaddleTrap: pip install "saddle-env[render]"') from exc
        if mode == "rgb_array" and "SDL_VIDEODRIVER" not in os.environ:
            os.environ["SDL_VIDEODRIVER"] = "dummy"  # no window needed; works headless
        self.pg = pygame
        self.config = config
        self.mode = mode
        pygame.display.init()  # not pygame.init(): that opens audio on servers
        pygame.font.init()
        self.font = pygame.font.Font(None, 20)
        self.window = None
        if mode == "human":
            self.window = pygame.display.set_mode((WIDTH, HEIGHT))
            pygame.display.set_caption("SaddleTrap")
            self.clock = pygame.time.Clock()
        self.surface = pygame.Surface((WIDTH, HEIGHT))
        self.trail: deque[tuple[float, float, float]] = deque(maxlen=TRAIL)
        # mesh of the saddle in body coordinates, polar grid up to the rim
        rim = config.rim_radius
        self.rings = [np.linspace(0, 2 * math.pi, 64) for _ in range(5)]
        self.ring_r = np.linspace(rim / 5, rim, 5)
        self.spokes = np.linspace(0, 2 * math.pi, 16, endpoint=False)

    def clear(self) -> None:
        """Forget the ball's trail (a new episode)."""
        self.trail.clear()

    # -- projection ------------------------------------------------------------------------
    def _perspective(self, X: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """Lab coordinates → left-panel pixels (camera 30° above the horizon)."""
        el = math.radians(30.0)
        scale = 170.0 / self.config.rim_radius
        depth = Y
        sx = 200 + scale * X
        sy = 230 - scale * (Z * math.cos(el) + depth * math.sin(el))
        return np.stack([sx, sy], axis=-1)

    def _top(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        scale = 85.0 / self.config.rim_radius
        return np.stack([500 + scale * X, 110 - scale * Y], axis=-1)

    # -- drawing ---------------------------------------------------------------------------
    def draw(self, scene, y: np.ndarray, ball: np.ndarray, obs: np.ndarray):
        """Draw one frame; returns it as an RGB array in "rgb_array" mode."""
        pg = self.pg
        surf = self.surface
        surf.fill(BACKGROUND)
        a, b, R = scene.a, scene.b, scene.radius
        theta = float(ball[S.B_THETA])
        ct, st = math.cos(theta), math.sin(theta)

        def lab(xb: np.ndarray, yb: np.ndarray, zb: np.ndarray | float):
            return ct * xb - st * yb, st * xb + ct * yb, zb

        # saddle mesh (rings and spokes of the polar grid), perspective
        for r in self.ring_r:
            phi = self.rings[0]
            xb, yb = r * np.cos(phi), r * np.sin(phi)
            pts = self._perspective(*lab(xb, yb, xb ** 2 / a - yb ** 2 / b))
            pg.draw.lines(surf, (150, 160, 180), True, pts.tolist(), 1)
        rr = np.linspace(0, self.config.rim_radius, 12)
        for phi in self.spokes:
            xb, yb = rr * math.cos(phi), rr * math.sin(phi)
            pts = self._perspective(*lab(xb, yb, xb ** 2 / a - yb ** 2 / b))
            pg.draw.lines(surf, (185, 190, 205), False, pts.tolist(), 1)
        # ball centre in the lab
        geo = K.geometry(a, b, R, float(y[0]), float(y[1]))
        cx, cy, cz = lab(np.array(geo.cx), np.array(geo.cy), np.array(geo.cz))
        self.trail.append((float(cx), float(cy), float(cz)))
        trail = np.array(self.trail)
        if len(trail) > 1:
            pts = self._perspective(trail[:, 0], trail[:, 1], trail[:, 2])
            pg.draw.lines(surf, (230, 140, 60), False, pts.tolist(), 2)
        centre = self._perspective(cx, cy, cz)
        radius_px = max(3, int(R * 170.0 / self.config.rim_radius))
        pg.draw.circle(surf, (200, 40, 40), centre.tolist(), radius_px)
        pg.draw.circle(surf, (90, 10, 10), centre.tolist(), radius_px, 1)

        # top view: rim, turning axes, trail, ball
        pg.draw.circle(surf, (120, 120, 120), (500, 110), 85, 1)
        for (ux, uy), colour in (((1.0, 0.0), (210, 60, 60)), ((0.0, 1.0), (60, 90, 210))):
            ex, ey = lab(np.array([-ux, ux]) * self.config.rim_radius,
                         np.array([-uy, uy]) * self.config.rim_radius, 0)[:2]
            pg.draw.line(surf, colour, *self._top(ex, ey).tolist(), 2)
        if len(trail) > 1:
            pg.draw.lines(surf, (230, 140, 60), False, self._top(trail[:, 0], trail[:, 1]).tolist(), 1)
        top_r = max(2, int(R * 85.0 / self.config.rim_radius))
        pg.draw.circle(surf, (200, 40, 40), self._top(cx, cy).tolist(), top_r)

        omega = float(ball[S.B_OMEGA])
        lines = [f"Omega = {omega:6.2f} rad/s", f"t = {float(ball[S.B_TIME]):6.2f} s",
                 f"R = {R * 100:.2f} cm, {scene.contact}"]
        for k, text in enumerate(lines):
            surf.blit(self.font.render(text, True, (30, 30, 30)), (420, 220 + 22 * k))
        # speed bar
        frac = min(1.0, max(0.0, omega / self.config.omega_max))
        pg.draw.rect(surf, (200, 200, 200), (420, 300, 160, 12), 1)
        pg.draw.rect(surf, (60, 140, 90), (420, 300, int(160 * frac), 12))

        if self.mode == "human":
            assert self.window is not None
            self.window.blit(surf, (0, 0))
            pg.event.pump()
            pg.display.flip()
            self.clock.tick(round(1.0 / self.config.control_period))
            return None
        return np.transpose(pg.surfarray.array3d(surf), (1, 0, 2)).copy()

    def close(self) -> None:
        """Close the window, if one is open."""
        if self.window is not None:
            self.pg.display.quit()
            self.window = None
