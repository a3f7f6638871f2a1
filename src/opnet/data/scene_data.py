"""The data module: synthetic (generated on first use) or existing IPA / Siléane scenes.

:class:`SceneData` holds all of it and needs no Lightning: eval.py and the tools that score a checkpoint use
it as it is, and start without loading Lightning. The configs' ``_target_`` is the same class as a
LightningDataModule, for train.py's Trainer: :class:`opnet.data.datamodule.OPNetDataModule`.

Splits are by cycle for IPA-layout data (scenes of one cycle share objects, so a scene-level split
would leak), by scene for Siléane data. Training samples get a random OpenCV resize interpolation
and the depth augmentations (docs/method.md#network-input); validation and test samples are resized with
``INTER_AREA`` and not augmented.
"""

from __future__ import annotations

import json
import logging
import numbers
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from opnet.data.cache import build_scene_cache, default_cache_dir
from opnet.data.preprocess import square_canvas
from opnet.data.roi import ROIScenes, parse_roi, roi_tag
from opnet.data.rotate import exact_without_segmentation
from opnet.data.sample import Batch, Sample, collate, make_sample, random_interpolation
from opnet.datasets import open_dataset
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.objects.model import ObjectModel
from opnet.settings_schema import check_value

if TYPE_CHECKING:  # the augmentation (albumentations) loads where training builds it
    from opnet.data.augment import DepthAugmenter

log = logging.getLogger(__name__)
CHECK_MODES = ("fast", "full", "off")


class SceneSamples(Dataset):
    """Samples of some scenes of a dataset.

    Training samples are made anew at every access (random interpolation and augmentation);
    validation and test samples are deterministic and kept once made (network resolution only).
    Scene records are read from the source at every access: nothing grows with the dataset.
    """

    def __init__(
        self,
        source: Any,
        indices: Sequence[int],
        input_size: int = 128,
        train: bool = False,
        augmenter: DepthAugmenter | None = None,
        random_resize: bool = True,
        fit: str = "pad",
    ) -> None:
        self.source = source
        self.fit = fit
        self.indices = list(indices)
        self.input_size = input_size
        self.train = train
        self.augmenter = augmenter if train else None
        self.random_resize = random_resize and train
        self._fixed: dict[int, Sample] = {}

    def __len__(self) -> int:
        return len(self.indices)

    def record(self, i: int) -> SceneRecord:
        return self.source[self.indices[i]]

    def clip_planes(self, probes: int = 16) -> tuple[float, float] | None:
        """The clip planes (metres) of these scenes' cameras, i.e. the depth normalization the
        network learns, read from up to ``probes`` scenes spread over them; None when they differ
        (several camera set-ups) or there are no scenes."""
        if not self.indices:
            return None
        picks = sorted({round(k * (len(self) - 1) / max(1, probes - 1)) for k in range(probes)})
        planes = {(float(c.clip_start), float(c.clip_end)) for c in (self.record(i).camera for i in picks)}
        return planes.pop() if len(planes) == 1 else None

    def __getitem__(self, i: int) -> Sample:
        if not self.train:
            if i not in self._fixed:
                self._fixed[i] = make_sample(self.record(i), self.input_size, cv2.INTER_AREA, fit=self.fit)
            return self._fixed[i]
        # torch's global generator is seeded by Lightning (main process and each worker), so the
        # augmentation stream is reproducible for a seed and differs between epochs
        rng = np.random.default_rng(int(torch.randint(0, 2**31 - 1, (1,))))
        if not self.random_resize:
            interp = cv2.INTER_AREA
        elif self.augmenter is not None:  # the augmentation config names the allowed options
            interp = self.augmenter.draw_interpolation(rng)
        else:
            interp = random_interpolation(rng)
        return make_sample(self.record(i), self.input_size, interp, self.augmenter, rng, fit=self.fit)


class ConcatScenes:
    """Several datasets (or their caches) as one: scenes in order, keys prefixed with the dataset's
    index and names with ``d<index>_`` so that they stay unique (e.g. training data of several
    camera set-ups)."""

    def __init__(self, sources: Sequence[Any]) -> None:
        self.sources = list(sources)
        self.offsets = np.cumsum([0] + [len(s) for s in self.sources])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def _locate(self, i: int) -> tuple[int, int]:
        k = int(np.searchsorted(self.offsets, i, side="right")) - 1
        return k, i - int(self.offsets[k])

    def __getitem__(self, i: int) -> SceneRecord:
        k, j = self._locate(i)
        record = self.sources[k][j]
        record.name = f"d{k}_{record.name}"
        return record

    def scenes(self) -> list[Any]:
        out = []
        for k, s in enumerate(self.sources):
            keys = s.scenes() if hasattr(s, "scenes") else list(range(len(s)))
            out += [(k, *key) if isinstance(key, tuple) else (k, key, 1) for key in keys]
        return out


def generated_views(root: Path) -> int:
    """``scene.views`` of a dataset made by opnet's generator (1 for any other dataset)."""
    path = Path(root) / "generation.json"
    try:
        views = json.loads(path.read_text(encoding="utf-8")).get("scene", {}).get("views", 1)
    except (OSError, ValueError, AttributeError):
        return 1
    return views if isinstance(views, int) and not isinstance(views, bool) and views >= 1 else 1


def as_paths(value: Any) -> list[Path]:
    """One folder or a list of folders (a Hydra list too) as a list of paths."""
    if value is None or value == "":
        return []
    if isinstance(value, (str, Path)):
        return [Path(value)]
    return [Path(v) for v in value]


def split_groups(
    keys: Sequence[Any], val_fraction: float, test_fraction: float, seed: int
) -> tuple[list[int], list[int], list[int]]:
    """Split item indices into train / val / test so that items with the same key stay together.

    Returns index lists; every split with a positive fraction gets at least one group when there
    are at least three groups.
    """
    groups = sorted(set(keys))
    order = np.random.default_rng(seed).permutation(len(groups))
    n = len(groups)
    n_test = max(1, round(test_fraction * n)) if test_fraction > 0 and n >= 3 else 0
    n_val = max(1, round(val_fraction * n)) if val_fraction > 0 and n >= 3 else 0
    test_g = {groups[k] for k in order[:n_test]}
    val_g = {groups[k] for k in order[n_test : n_test + n_val]}
    train, val, test = [], [], []
    for idx, key in enumerate(keys):
        (test if key in test_g else val if key in val_g else train).append(idx)
    return train, val, test


def cache_fit(source: Any, fit: str) -> str:
    """The framing a dataset's cache is stored under: ``pad`` when the dataset has one camera whose
    ``fit`` canvas is the ``pad`` canvas (a centred principal point: the caches made before other
    framings existed stay valid), else ``fit``."""
    camera = getattr(source, "camera", None)
    if isinstance(camera, Camera) and square_canvas(camera, fit) == square_canvas(camera, "pad"):
        return "pad"
    return fit


class SceneData:
    """Serves depth scenes as network samples (the hooks of a LightningDataModule, without Lightning).

    Args:
        obj: the object model the scenes show (used to generate synthetic data).
        root: dataset folder (IPA layout with parameter.json, or Siléane with camera_params.txt),
            or a list of them, trained on together (e.g. several camera set-ups).
        generate: if given and ``root`` is not a complete dataset yet, generate it first with
            these settings (cycles, drops, workers, seed, scene: SceneConfig fields).
        input_size: network input side in pixels.
        val_fraction, test_fraction: share of cycles (IPA) or scenes (Siléane) per split.
        include_empty: keep scenes with no object (scene 000 of every cycle).
        batch_size, num_workers: DataLoader settings.
        augmenter: sim-to-real augmentation for training, or None.
        random_interpolation: draw the resize interpolation at random during training.
        seed: split seed.
        cache: read the scenes from a scene cache (:mod:`opnet.data.cache`: built once, after
            generation; bounded memory, fast reads) instead of the dataset files.
        cache_size: side of the cached canvas in pixels; None = twice ``input_size``.
        cache_dir: where the cache lives; None = ``<root>/cache_s<size>`` (``_<fit>`` appended for a
            framing whose canvases differ from ``pad``'s, see :func:`cache_fit`).
        cache_workers: processes that build the cache.
        test_root: a separate dataset (or a list) whose scenes, all of them, form the test split;
            the ``test_fraction`` of ``root`` is then not held out.
        check: before anything is read, check every dataset (:mod:`opnet.datasets.check`):
            ``"fast"`` (headers and sizes, seconds), ``"full"`` (every file decoded and
            validated) or ``"off"``. A problem stops the run at once, naming the file.
        object_id: for a BOP split folder: the ``obj_id`` whose instances are the ground truth.
        clip: for BOP data: (near, far) working range in metres (None: from the first image).
        train_groups: train on the first N groups (piles of a generated dataset, else cycles or
            scenes; sorted by dataset and group) of the training split only, the validation and
            test splits unchanged: the data-scaling curve at fixed held-out data. None: all.
        fit: how an image becomes the square network input (:data:`opnet.settings_schema.CANVAS_FITS`):
            ``image`` (centred on the image, short side padded: the configs' default), ``pad``
            (centred on the principal point: this argument's default, the framing of checkpoints
            without the key), ``crop``, ``image_crop``. The checkpoint keeps it: eval.py,
            predict.py and the ONNX export frame images the same way.
        roi: region of interest cropped before the framing (:mod:`opnet.data.roi`): None, an
            ``[x0, y0, x1, y1]`` pixel box or ``"auto"``; the checkpoint keeps it like ``fit``.
        val_root: a separate dataset (or a list) whose scenes, all of them, form the validation split
            (the checkpoint kept, the learning curve's validation AP and the decoding tuned after training
            all choose on it); the ``val_fraction`` of ``root`` is then not held out.
        test_min_objects: score only the scenes of ``test_root`` and ``val_root`` with at least this many parts
            (e.g. 70 for the Siléane-like bulk piles of 70-80 parts); 0 = every scene.
    """

    def __init__(
        self,
        obj: ObjectModel,
        root: str | Path | Sequence[str | Path],
        generate: Mapping[str, Any] | None = None,
        input_size: int = 128,
        val_fraction: float = 0.1,
        test_fraction: float = 0.1,
        include_empty: bool = False,
        batch_size: int = 16,
        num_workers: int = 0,
        augmenter: DepthAugmenter | None = None,
        random_interpolation: bool = True,
        seed: int = 0,
        object_config: Mapping[str, Any] | None = None,
        cache: bool = True,
        cache_size: int | None = None,
        cache_dir: str | Path | None = None,
        cache_workers: int = 1,
        test_root: str | Path | Sequence[str | Path] | None = None,
        check: str = "fast",
        object_id: int | None = None,
        clip: Sequence[float] | None = None,
        fit: str = "pad",
        test_min_objects: int = 0,
        val_root: str | Path | Sequence[str | Path] | None = None,
        train_groups: int | None = None,
        roi: Any = None,
    ) -> None:
        super().__init__()
        self.roi = parse_roi(roi)
        self.fit = check_value("fit", fit, "data.fit")
        if check not in CHECK_MODES:
            raise ValueError(f"data.check={check!r}, expected one of {CHECK_MODES}")
        self.check = check
        self.object_id = int(object_id) if object_id is not None else None
        self.clip = check_value("trained_clip", clip, "data.clip")  # [near, far] metres, as a checkpoint's planes
        self.obj = obj
        self.roots = as_paths(root)
        if not self.roots:
            raise ValueError("data.root: no dataset folder given")
        self.root = self.roots[0]
        if generate is not None and len(self.roots) > 1:
            raise ValueError("data.generate: synthetic data is generated into one data.root, not a list")
        self.generate = dict(generate) if generate is not None else None
        self.input_size = input_size
        for key, value in (("val_fraction", val_fraction), ("test_fraction", test_fraction)):
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0 <= value < 1:
                raise ValueError(f"data.{key}={value!r}: expected the share of the scenes held out, a number in [0, 1)")
        if not val_fraction + test_fraction < 1:
            raise ValueError(f"data.val_fraction={val_fraction} and data.test_fraction={test_fraction} leave no scene "
                             "to train on; their sum must be below 1")
        for key, value, low in (("batch_size", batch_size, 1), ("num_workers", num_workers, 0),
                                ("seed", 0 if seed is None else seed, 0)):  # seed null: a split drawn at random
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
                raise ValueError(f"data.{key}={value!r}: expected a whole number >= {low}")
        self.val_fraction, self.test_fraction = val_fraction, test_fraction
        self.include_empty = include_empty
        self.batch_size, self.num_workers = batch_size, num_workers
        self.augmenter = augmenter
        self.random_interpolation = random_interpolation
        self.seed = seed
        self.object_config = dict(object_config) if object_config is not None else None
        self.cache = bool(cache)
        self.cache_size = int(cache_size) if cache_size is not None else 2 * int(input_size)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None  # None: per dataset, by its framing
        self.cache_workers = int(cache_workers)
        self.test_roots = as_paths(test_root)
        self.val_roots = as_paths(val_root)
        if isinstance(test_min_objects, bool) or int(test_min_objects) < 0:
            raise ValueError(f"data.test_min_objects={test_min_objects!r}, expected an integer >= 0")
        self.test_min_objects = int(test_min_objects)
        if train_groups is not None and (isinstance(train_groups, bool) or not isinstance(train_groups, int)
                                         or train_groups < 1):
            raise ValueError(f"data.train_groups={train_groups!r}, expected null or an integer >= 1")
        self.train_groups = train_groups
        self.test_root = self.test_roots[0] if self.test_roots else None
        self.splits: dict[str, SceneSamples] = {}

    def prepare_data(self) -> None:
        """Generate the synthetic dataset if it is configured and not complete (resumable), then
        build (or complete) its scene cache."""
        if self.generate is None:
            for root in self.roots:
                if not root.exists():
                    raise FileNotFoundError(f"{root}: dataset folder not found (and no 'generate' settings)")
        else:
            from opnet.synthesis import SceneConfig, generate_dataset

            g = dict(self.generate)
            scene = SceneConfig.from_dict(dict(g.pop("scene", None) or {}))
            log.info("preparing synthetic dataset at %s", self.root)
            generate_dataset(self.obj, self.root, scene=scene, object_config=self.object_config, **g)
        if self.check != "off":
            self._check_datasets()
        if self.cache:
            self._open_sources(self.roots)
            self._open_sources(self.test_roots)
            self._open_sources(self.val_roots)

    @property
    def _every_root(self) -> list[Path]:
        """The training datasets, then those of a split of their own (validation, test)."""
        return [*self.roots, *self.val_roots, *self.test_roots]

    def _check_datasets(self) -> None:
        """Every file of every dataset, before the first is used (fast: headers and sizes)."""
        from opnet.datasets.check import check_dataset

        for root in self._every_root:
            report = check_dataset(root, fast=self.check == "fast", object_id=self.object_id, clip=self.clip)
            log.info("dataset check (%s): %s", self.check, report.summary(0).replace("\n", " "))
            if not report.ok:
                raise ValueError(
                    f"{report.problems[0]} ({len(report.problems)} problem(s) in {root}; all of them: "
                    f"python -m opnet.datasets.check {root})"
                )

    def _open_sources(self, roots: Sequence[Path]) -> Any:
        """The datasets (one, or concatenated), or their scene caches (built or completed first)."""
        sources = []
        for root in roots:
            source = open_dataset(root, object_id=self.object_id, clip=self.clip)
            if self.roi is not None:
                source = ROIScenes(source, self.roi)
            if self.cache:
                single = root == self.root and len(self.roots) == 1
                fit = cache_fit(source, self.fit)
                cache_dir = self.cache_dir if single and self.cache_dir is not None else \
                    default_cache_dir(root, self.cache_size, fit, roi_tag(self.roi))
                source = build_scene_cache(source, cache_dir, self.cache_size, workers=self.cache_workers, fit=fit)
            sources.append(source)
        return sources[0] if len(sources) == 1 else ConcatScenes(sources)

    def setup(self, stage: str | None = None) -> None:
        if self.splits:
            return
        for root in self._every_root:
            self._check_object(root)
        self._check_rotation()
        source = self._open_sources(self.roots)
        keys, keep = self._scene_keys(source, self.roots)
        test_fraction = 0.0 if self.test_root is not None else self.test_fraction
        val_fraction = 0.0 if self.val_roots else self.val_fraction
        tr, va, te = split_groups([keys[i] for i in keep], val_fraction, test_fraction, self.seed)
        if self.train_groups is not None:  # the data-scaling curve: the first N training groups only
            first = set(sorted({keys[keep[i]] for i in tr})[: self.train_groups])
            tr = [i for i in tr if keys[keep[i]] in first]
        pick = lambda idx: [keep[i] for i in idx]  # noqa: E731
        # a cached scene is already framed (its canvas is the image): framing it again is the identity
        common = dict(input_size=self.input_size, fit=self.fit)
        self.splits = {
            "train": SceneSamples(source, pick(tr), train=True, augmenter=self.augmenter,
                                  random_resize=self.random_interpolation, **common),
            "val": SceneSamples(source, pick(va), **common),
            "test": SceneSamples(source, pick(te), **common),
        }
        for split, roots in (("val", self.val_roots), ("test", self.test_roots)):
            if roots:  # datasets of their own (other seed, other generator)
                own = self._open_sources(roots)
                self.splits[split] = SceneSamples(own, self._scene_keys(own, roots, self.test_min_objects)[1], **common)
        log.info("dataset %s: %s", ", ".join(map(str, self.roots)), {k: len(v) for k, v in self.splits.items()})

    def _check_rotation(self) -> None:
        """Refuse in-plane rotations a training dataset cannot follow exactly: turns other than
        180 degrees need the segmentation to recount visibilities (:mod:`opnet.data.rotate`)."""
        aug = self.augmenter
        if aug is None or aug.p_rotate == 0 or exact_without_segmentation(*aug.rotate_deg):
            return
        for root in self.roots:
            dataset = open_dataset(root, object_id=self.object_id, clip=self.clip)
            if len(dataset) and dataset[0].segmentation is None:
                raise ValueError(
                    f"{root}: augmentation.p_rotate={aug.p_rotate} turns scenes by {aug.rotate_deg} degrees, but this "
                    "dataset has no segmentation to recount the parts' visibility after a turn; set "
                    "augmentation.p_rotate=0 or augmentation.rotate_deg=[180,180] (exact without it)"
                )

    def _check_object(self, root: Path) -> None:
        """Refuse a dataset made of another part (its ``object.json`` names the object)."""
        path = root / "object.json"
        if not path.is_file():
            return
        try:
            name = json.loads(path.read_text()).get("name")
        except (OSError, ValueError, AttributeError) as e:
            raise ValueError(f"{path}: cannot read the dataset's object ({e})") from e
        if name is not None and name != self.obj.name:
            raise ValueError(
                f"{path}: the dataset shows object {name!r} but the run is configured for "
                f"{self.obj.name!r}; set object={name} or point data.root at a dataset of {self.obj.name!r}"
            )

    def _scene_keys(self, source: Any, roots: Sequence[Path], min_objects: int = 0) -> tuple[list[Any], list[int]]:
        """Group key per scene and the scenes to keep (scenes with objects, unless
        ``include_empty``; with at least ``min_objects`` parts where the count is known).

        The group is what splits must not cut: the cycle of IPA-layout keys ``(cycle, objects)``,
        the pile (``cycle // views``) of a dataset generated with several views per pile, the BOP
        scene of ``(scene, image, objects)``, the scene name otherwise; with several datasets the
        dataset index comes first."""
        scenes = source.scenes() if hasattr(source, "scenes") else list(range(len(source)))
        views = [generated_views(root) for root in roots]
        concat = len(roots) > 1
        keys, keep = [], []
        for i, s in enumerate(scenes):
            is_ipa = isinstance(s, tuple)  # (group, ..., objects): IPA (cycle, objects), BOP (scene, image, objects)
            if is_ipa:
                k, inner = (s[0], s[1:]) if concat else (0, s)
                group = inner[0] // views[k] if isinstance(inner[0], (int, np.integer)) else inner[0]
                keys.append((k, group) if concat else (group,))
            else:
                keys.append(s)
            if (self.include_empty or not is_ipa or s[-1] > 0) and (not is_ipa or s[-1] >= min_objects):
                keep.append(i)
        return keys, keep

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        ds = self.splits[split]
        return DataLoader(
            ds, batch_size=self.batch_size, shuffle=shuffle, num_workers=self.num_workers,
            collate_fn=collate, persistent_workers=self.num_workers > 0, drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)

    def transfer_batch_to_device(self, batch: Any, device: torch.device, dataloader_idx: int) -> Any:
        return batch.to(device) if isinstance(batch, Batch) else super().transfer_batch_to_device(batch, device, dataloader_idx)

