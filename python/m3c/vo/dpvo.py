"""DPVO's networks as the front-end of M3C's patch VO (cpp/vo/front_end.h): they place the patches and measure
where each patch is seen in a new frame, with a confidence; the C++ patch graph and Ceres bundle adjustment do
the rest (m3c._core.PatchVO(front_end=...)).

Per frame (at the VO's processing resolution, cropped to multiples of 4): DPVO's matching and context features
(m3c.models.dpvo). Patches: DPVO's GRADIENT_BIAS sampling (3x candidates at 1/4 resolution, the best by pooled
image gradient), with the gradient zeroed inside the people's masks (the thesis's change); a patch's centre at
feature pixel c is image pixel 4 c, as in DPVO. Measurement of patch k (host frame i) in frame j: its 3 x 3 pixels
placed around the VO's predicted centre, then `iterations` steps of correlation + update operator, each moving the
centre by the operator's flow revision; the edge's hidden state is kept for the next time the VO asks for the same
edge. The measurement's weight is the mean of the operator's two confidences.

Where this differs from DPVO: DPVO reprojects every pixel of a patch with its depth and runs the operator over all
edges of the window at once (so c1/c2 see the same patch's neighbouring edges, and agg_kk all of a patch's edges);
here one call holds the edges into one target frame, so those terms see only what that call holds, and the 3 x 3
pixels are placed as a fronto-parallel square.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from m3c.models.dpvo import RESOLUTION, DPVONet, correlation, patch_features


class DPVOFrontEnd:
    """model: DPVONet (m3c.models.dpvo.load_dpvo). iterations: update steps per measurement. min_weight: a
    measurement whose confidence is below this is dropped."""

    def __init__(self, model: DPVONet, iterations: int = 2, candidate_factor: int = 3, min_weight: float = 0.05,
                 seed: int = 0):
        import torch

        if iterations < 1 or candidate_factor < 1:
            raise ValueError("iterations and candidate_factor must be >= 1")
        self._torch = torch
        self.model = model.eval()
        self.iterations, self.candidate_factor, self.min_weight = iterations, candidate_factor, min_weight
        self.seed = seed
        self._pending: deque = deque()
        self._frames: dict = {}  # frame -> (fmap, imap, gradient, (h, w))
        self._samples: dict = {}  # frame -> (centres in image pixels (n, 2), gmap (n, 128, 3, 3), context (n, 384))
        self._patches: dict = {}  # (frame, u, v) -> (patch id, gmap, context)
        self._states: dict = {}  # (patch id, target) -> hidden state (384,)
        self._next_id = 0
        offsets = torch.arange(-1.0, 2.0)
        oy, ox = torch.meshgrid(offsets, offsets, indexing="ij")
        self._grid = torch.stack([ox, oy], dim=-1)

    def push_image(self, image: np.ndarray) -> None:
        """The colour frame (H, W, 3) uint8 BGR the next add_frame belongs to (the VO passes only gray)."""
        self._pending.append(image)

    # --- the FrontEnd interface (called by the C++ PatchVO) ------------------------------------------------
    def add_frame(self, frame: int, gray: np.ndarray, mask: np.ndarray | None) -> None:
        import cv2

        torch = self._torch
        h, w = gray.shape
        colour = self._pending.popleft() if self._pending else np.repeat(gray[..., None], 3, axis=2)
        if colour.shape[:2] != (h, w):
            colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_AREA)
        h4, w4 = h // RESOLUTION * RESOLUTION, w // RESOLUTION * RESOLUTION
        if h4 < 4 * RESOLUTION or w4 < 4 * RESOLUTION:
            raise ValueError(f"frame {frame} is too small for DPVO's features ({w} x {h})")
        image = np.ascontiguousarray(colour[:h4, :w4])
        fmap, imap = self.model.encode(torch.from_numpy(image[None]))
        # DPVO's gradient: channel sum, forward differences, magnitude, 4 x 4 average; zero on people (thesis).
        g = image.astype(np.float64).sum(axis=2)
        dx, dy = g[:-1, 1:] - g[:-1, :-1], g[1:, :-1] - g[:-1, :-1]
        mag = np.zeros((h4, w4))
        mag[:-1, :-1] = np.sqrt(dx ** 2 + dy ** 2)
        if mask is not None:
            mag[np.asarray(mask)[:h4, :w4] > 0] = 0.0
            people = (np.asarray(mask)[:h4, :w4] > 0).reshape(h4 // 4, 4, w4 // 4, 4).any(axis=(1, 3))
        else:
            people = np.zeros((h4 // 4, w4 // 4), dtype=bool)
        pooled = mag.reshape(h4 // 4, 4, w4 // 4, 4).mean(axis=(1, 3))
        pooled[people] = 0.0
        self._frames[frame] = (fmap[0], imap[0], pooled, (h4, w4))

    def sample_patches(self, frame: int, count: int) -> np.ndarray:
        if frame not in self._samples:
            fmap, imap, pooled, _ = self._frames[frame]
            fh, fw = pooled.shape
            rng = np.random.default_rng([self.seed, frame])
            n = self.candidate_factor * count
            x, y = rng.integers(1, fw - 1, n), rng.integers(1, fh - 1, n)
            score = pooled[y, x]
            order = np.argsort(-score, kind="stable")
            keep = [i for i in order[:count] if score[i] > 0]
            centres = np.column_stack([x[keep], y[keep]]).astype(np.float64)
            gmap, context = patch_features(fmap, imap, self._torch.from_numpy(centres).float())
            self._samples[frame] = (RESOLUTION * centres, gmap, context)
        centres, gmap, context = self._samples[frame]
        for k, (u, v) in enumerate(centres[:count]):
            if (frame, u, v) not in self._patches:
                self._patches[(frame, u, v)] = (self._next_id, gmap[k], context[k])
                self._next_id += 1
        return centres[:count]

    def _patch(self, host: int, u: float, v: float):
        key = (host, float(u), float(v))
        if key not in self._patches:  # a patch the VO placed itself: features at its (sub-pixel) centre
            fmap, imap, _, _ = self._frames[host]
            centre = self._torch.tensor([[u / RESOLUTION, v / RESOLUTION]], dtype=self._torch.float32)
            gmap, context = patch_features(fmap, imap, centre)
            self._patches[key] = (self._next_id, gmap[0], context[0])
            self._next_id += 1
        return self._patches[key]

    def track(self, target: int, hosts: np.ndarray, host_uv: np.ndarray, predicted_uv: np.ndarray):
        torch = self._torch
        n = len(hosts)
        if n == 0:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=bool)
        fmap, _, _, (h4, w4) = self._frames[target]
        patches = [self._patch(int(i), u, v) for i, (u, v) in zip(hosts, host_uv)]
        kk = torch.tensor([p[0] for p in patches])
        gmap = torch.stack([p[1] for p in patches])
        context = torch.stack([p[2] for p in patches])[None]
        net = torch.stack([self._states.get((int(k), target), torch.zeros(context.shape[-1])) for k in kk])[None]
        centre = torch.from_numpy(np.asarray(predicted_uv, dtype=np.float32) / RESOLUTION)
        ii = torch.from_numpy(np.asarray(hosts, dtype=np.int64))
        jj = torch.full((n,), target, dtype=torch.long)
        with torch.no_grad():
            for _ in range(self.iterations):
                corr = correlation(gmap, fmap, centre[:, None, None, :] + self._grid)
                net, delta, weight = self.model.update(net, context, corr[None], ii, jj, kk)
                centre = centre + delta[0]
        for k, state in zip(kk.tolist(), net[0]):
            self._states[(k, target)] = state
        uv = RESOLUTION * centre.double().numpy()
        w = weight[0].double().mean(dim=1).numpy()
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w4 - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h4 - 1)
        return uv, w, inside & (w >= self.min_weight) & np.isfinite(uv).all(axis=1)

    def release_frame(self, frame: int) -> None:
        self._frames.pop(frame, None)
        self._samples.pop(frame, None)
        gone = {pid for (host, _, _), (pid, _, _) in self._patches.items() if host == frame}
        self._patches = {k: p for k, p in self._patches.items() if k[0] != frame}
        self._states = {k: s for k, s in self._states.items() if k[1] != frame and k[0] not in gone}


__all__ = ["DPVOFrontEnd"]
