"""Top view of the bogie on the track (pygame), for ``render_mode="rgb_array"`` or ``"human"``.

Lateral motion is millimetres on a bogie metres long, so lateral displacements and yaw are
drawn magnified (``LATERAL_GAIN``); the flange clearance is drawn at the same gain, so a
wheelset touching the red band is in flange contact.
"""

from __future__ import annotations

import math

import numpy as np

from ..dynamics import P_DELTA, P_E, P_L1

LATERAL_GAIN = 40.0  # drawn lateral displacement per real displacement
WIDTH, HEIGHT = 600, 400
PIXELS_PER_M = 90.0


class BogieRenderer:
    def __init__(self, task, mode: str, fps: int) -> None:
        try:
            import pygame
        except ImportError as error:  # pragma: no cover - depends on the install
            from gymnasium.error import DependencyNotInstalled

            raise DependencyNotInstalled('rendering needs pygame: pip install "bogie-env[render]"') from error
        self.pygame = pygame
        self.task = task
        self.mode = mode
        self.fps = fps
        self.window = None
        self.clock = None
        if mode == "human":
            pygame.display.init()
            self.window = pygame.display.set_mode((WIDTH, HEIGHT))
            pygame.display.set_caption("bogie-env: hunting")
            self.clock = pygame.time.Clock()
        pygame.font.init()
        self.font = pygame.font.Font(None, 22)
        self.surface = pygame.Surface((WIDTH, HEIGHT))

    def _to_screen(self, x_m: float, y_m: float) -> tuple[int, int]:
        """Track coordinates (x forward to the right of the screen, y left up the screen)."""
        return int(WIDTH / 2 + x_m * PIXELS_PER_M), int(HEIGHT / 2 - y_m * PIXELS_PER_M)

    def _box(self, centre_x, centre_y, yaw, length, width, colour, filled=True):
        pygame = self.pygame
        c, s = math.cos(yaw), math.sin(yaw)
        corners = []
        for dx, dy in ((length / 2, width / 2), (length / 2, -width / 2), (-length / 2, -width / 2), (-length / 2, width / 2)):
            corners.append(self._to_screen(centre_x + c * dx - s * dy, centre_y + s * dx + c * dy))
        pygame.draw.polygon(self.surface, colour, corners, 0 if filled else 2)

    def render(self, row: int):
        pygame = self.pygame
        task = self.task
        p = task.P[row]
        x = task.x[row]
        e, L1, delta = p[P_E], p[P_L1], p[P_DELTA]
        g = LATERAL_GAIN
        self.surface.fill((245, 245, 240))
        distance = task.distance_m[row]
        xs = np.linspace(-WIDTH / 2 / PIXELS_PER_M, WIDTH / 2 / PIXELS_PER_M, 60)
        alignment = task.track.at(distance + xs) if task.track.values.size else np.zeros_like(xs)
        for side in (1.0, -1.0):
            rail = [self._to_screen(xx, side * e + g * yy) for xx, yy in zip(xs, alignment)]
            pygame.draw.lines(self.surface, (90, 90, 90), False, rail, 4)
            for bound in (1.0, -1.0):  # flange clearance band around each rail, at the same gain
                band = [self._to_screen(xx, side * e + g * (yy + bound * delta)) for xx, yy in zip(xs, alignment)]
                pygame.draw.lines(self.surface, (220, 120, 120), False, band, 1)
        for i, x_pos in ((0, L1), (1, -L1)):
            y, psi = x[8 * i], x[8 * i + 4]
            self._box(x_pos, g * y, g * psi, 0.25, 2 * e + 0.1, (40, 60, 160))
            for side in (1.0, -1.0):
                self._box(x_pos - side * e * g * psi, side * e + g * y, g * psi, 0.92, 0.12, (20, 20, 20))
        self._box(0.0, g * x[16], g * x[18], 2 * L1 + 0.6, 2 * e - 0.2, (30, 140, 60), filled=False)
        hunting = bool(task.hunting[row])
        lines = [
            f"speed {task.speed_kmh[row]:6.1f} km/h",
            f"rms |y - track| {1e3 * task.lateral_rms_m[row].max():5.2f} mm (hunting at {1e3 * task.config['hunting']['rms_fraction'] * delta:.1f})",
            f"lateral x{g:g}" + ("   HUNTING" if hunting else ""),
        ]
        for k, text in enumerate(lines):
            colour = (200, 0, 0) if hunting and k == 2 else (0, 0, 0)
            self.surface.blit(self.font.render(text, True, colour), (10, 10 + 20 * k))
        if self.mode == "human":
            self.window.blit(self.surface, (0, 0))
            pygame.event.pump()
            pygame.display.flip()
            self.clock.tick(self.fps)
            return None
        return np.transpose(np.array(pygame.surfarray.pixels3d(self.surface)), axes=(1, 0, 2)).copy()

    def close(self) -> None:
        if self.window is not None:
            self.pygame.display.quit()
            self.window = None
