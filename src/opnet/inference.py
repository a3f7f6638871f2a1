"""The fast inference path of ``predict.py`` and ``eval.py``: network form, memory format,
precision, compilation. What each setting buys on a 2-core CPU and on a GPU is measured by
``scripts/bench/bench_infer.py`` and ``scripts/bench/profile_graph.py`` (docs/deployment.md
"Inference speed", results/speed/README.md, results/gpu/README.md); the figures live there.

``inference.precision``: ``32`` (the default: the poses of fp32 eager, to float32 rounding),
``bf16`` (autocast), or ``auto`` = bf16 where the hardware computes it natively (CPUs with
AVX512-BF16 / AMX, CUDA GPUs), fp32 elsewhere.
``inference.fused``: ``auto`` = on for fp32 on the CPU: :class:`opnet.models.fused.FusedDenseNet`,
the network rewritten for inference (block buffers instead of concatenations, batch norms folded,
prepacked oneDNN convolutions, transitions pooled first; about the matrix-product roofline time of
the paper network); ``false`` = the training module as it is.
``inference.channels_last``: ``auto`` = on (faster on CPUs and GPUs alike for this network).
``inference.compile``: ``torch.compile`` the (unfused) backbone (worth it for long runs or a
service: the first call compiles for tens of seconds).
``inference.max_batch``: larger batches run in chunks of this many images; ``auto`` = 8 for the
unfused paths; for the fused form as many images as keep its largest block buffer within
``CHUNK_BYTES`` (8 MiB), at most 8: 1 for the paper network (6.5 MB per image: larger chunks were
slower per image), 8 for the small and tiny presets.
``inference.device_side``: ``auto`` = on for a CUDA device, off on the CPU. On: predict.py's
preprocessing (:mod:`opnet.data.preprocess_torch`) and the pose averaging of predict.py, eval.py
and validation (:mod:`opnet.parameterizations.averaging_torch`) run as torch operations on the
model's device, every image of a batch at once, and the poses come to the host in one transfer;
off: OpenCV / numpy on the host, image by image. Both give the same input and poses to float
rounding (tests). On a 2-core CPU the host is the faster of the two (docs/deployment.md
"Device-side inference"): OpenCV's resize and the k-d tree beat tens of small torch operations.
``inference.cuda_graph``: ``auto`` = on for a CUDA device: a batch of one image runs as a CUDA graph
(captured at its first call, then replayed: one launch instead of one per kernel); with
``device_side`` on as well, ``predict.py`` runs each image whole as one graph
(:class:`GraphedPipeline`: preprocessing, network, decoding and averaging with every shape fixed by
the grid, :mod:`opnet.parameterizations.dense_decoding`; the host only copies the depth in, the
table out, and projects the averaged rotations). On the CPU it is off, with a log line when asked
for (``true``).
``inference.compile_pipeline`` (false): the whole-image graph's preprocessing and decoding are
``torch.compile``'d (fused into a few kernels, compiled at the first image; faster end to end on a
GPU: ``scripts/bench/profile_graph.py --fuse``, results/gpu/README.md).
``inference.workers``: chunks of a batch run on this many threads at once, each computing with one
core; ``auto`` = the torch thread count for the fused form, 1 (one chunk after the other on all
cores) otherwise (two workers were a little faster for the fused paper network, a tie for the small
preset). A batch of one chunk runs on all cores.

bf16 changes the network output by a few 1e-3, so its poses are not those of fp32
(``scripts/bench/check_inference.py`` pairs the hypotheses of both on the quickstart model's test
scenes: results/speed/README.md), which is why fp32 stays the default and bf16 is a documented opt-in.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

from opnet._limits import check_threads
from opnet._repr import short_repr
from opnet.hardware import cpu_has_native_bf16

PRECISIONS = ("auto", "32", "bf16")
AUTO_BOOL = ("auto", True, False)
KEYS = ("precision", "fused", "channels_last", "compile", "max_batch", "workers", "device_side", "cuda_graph",
        "compile_pipeline")
#: the fused form's automatic chunk keeps its largest block buffer within this many bytes
CHUNK_BYTES = 8 << 20
MAX_CHUNK = 8

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InferenceSettings:
    precision: str = "32"
    channels_last: bool | str = "auto"
    compile: bool = False
    #: larger batches run in chunks of this many images ("auto": see the module docstring): the
    #: DenseNet's activations of a large batch no longer fit the caches (docs/deployment.md)
    max_batch: int | str = "auto"
    fused: bool | str = "auto"
    workers: int | str = "auto"
    #: preprocessing and averaging as torch operations on the model's device ("auto": on CUDA)
    device_side: bool | str = "auto"
    #: batch-1 forwards replayed as a CUDA graph ("auto": on CUDA; the CPU falls back with a log line)
    cuda_graph: bool | str = "auto"
    #: the whole-image graph's preprocessing and decoding compiled (GraphedPipeline(fuse=True))
    compile_pipeline: bool = False

    @classmethod
    def from_config(cls, cfg: Any) -> InferenceSettings:
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(KEYS)
        if unknown:
            raise ValueError(f"inference: unknown keys {sorted(unknown)}; expected {', '.join(KEYS)}")
        precision = str(cfg.get("precision", "32"))
        if precision not in PRECISIONS:
            raise ValueError(f"inference.precision={precision!r}, expected one of {PRECISIONS}")
        for key in ("channels_last", "fused"):
            if cfg.get(key, "auto") not in AUTO_BOOL:
                raise ValueError(f"inference.{key}={cfg[key]!r}, expected auto, true or false")
        for key in ("device_side", "cuda_graph"):
            if not is_auto_bool(cfg.get(key, "auto")):
                raise ValueError(f"inference.{key}={short_repr(cfg[key])}, expected auto, true or false")
        value = cfg.get("max_batch", "auto")
        if value != "auto" and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ValueError(f"inference.max_batch={short_repr(value)}, expected a positive integer or auto")
        if cfg.get("workers", "auto") != "auto":
            check_threads(cfg["workers"], "inference.workers")
        for key in ("compile", "compile_pipeline"):
            if not isinstance(cfg.get(key, False), bool):
                raise ValueError(f"inference.{key}={short_repr(cfg[key])}, expected true or false")
        return cls(precision, cfg.get("channels_last", "auto"), bool(cfg.get("compile", False)),
                   cfg.get("max_batch", "auto"), cfg.get("fused", "auto"), cfg.get("workers", "auto"),
                   cfg.get("device_side", "auto"), cfg.get("cuda_graph", "auto"), cfg.get("compile_pipeline", False))

    def resolved(self, device: torch.device, backbone: torch.nn.Module | None = None) -> tuple[bool, bool, bool]:
        """(bf16, channels_last, fused) for ``device`` (and ``backbone``: whether it can be fused).

        Raises:
            ValueError: ``fused=true`` with bf16, ``compile`` or a network the fused form does not cover.
        """
        if self.precision == "auto":
            bf16 = device.type == "cuda" or (device.type == "cpu" and cpu_has_native_bf16())
        else:
            bf16 = self.precision == "bf16"
        cl = True if self.channels_last == "auto" else bool(self.channels_last)
        why_not = _why_not_fused(device, backbone, bf16, self.compile)
        if self.fused is True and why_not:
            raise ValueError(f"inference.fused=true: {why_not}; use inference.fused=auto or false")
        fused = self.fused is not False and not why_not
        return bf16, cl, fused

    def on_device(self, device: torch.device) -> bool:
        """Whether preprocessing and averaging run on ``device`` (``device_side``)."""
        return device_side(self.device_side, device)

    def graphed(self, device: torch.device) -> bool:
        """Whether a batch of one image runs as a CUDA graph on ``device`` (never compiled)."""
        if self.cuda_graph is False or self.compile:
            return False
        return device.type == "cuda"

    def chunk(self, bytes_per_image: int | None = None) -> int:
        """Images per forward call; ``bytes_per_image``: the fused form's largest block buffer."""
        if self.max_batch != "auto":
            return int(self.max_batch)
        if bytes_per_image is None:
            return MAX_CHUNK
        return max(1, min(MAX_CHUNK, CHUNK_BYTES // max(1, bytes_per_image)))

    def describe(self, device: torch.device, backbone: torch.nn.Module | None = None) -> str:
        bf16, cl, fused = self.resolved(device, backbone)
        form = "fused fp32" if fused else ("bf16 autocast" if bf16 else "fp32")
        layout = "channels-last" if cl or fused else "contiguous"
        per_image = None
        if fused and backbone is not None:
            from opnet.models.fused import largest_block_bytes

            per_image = largest_block_bytes(backbone)
        workers = self.threads(fused)
        whole = self.graphed(device) and self.on_device(device)
        extras = [", CUDA graph at batch 1" if self.graphed(device) else "",
                  ", preprocessing and averaging on the device" if self.on_device(device) else "",
                  (", predict.py's images whole as one graph" + (" (pre- and postprocessing compiled)"
                                                                 if self.compile_pipeline else "")) if whole else ""]
        return (f"{form}, {layout}{', compiled' if self.compile else ''}, chunks of {self.chunk(per_image)}"
                f"{f' on {workers} workers' if workers > 1 else ''}{''.join(extras)} on {device.type}")

    def threads(self, fused: bool) -> int:
        """Worker threads for the chunks of a batch (each computing with one core)."""
        if self.workers == "auto":
            return torch.get_num_threads() if fused else 1
        return int(self.workers)


def is_auto_bool(value: object) -> bool:
    """``auto``, true or false (a number is neither: 1 is no switch)."""
    return value == "auto" if isinstance(value, str) else isinstance(value, bool)


def device_side(setting: bool | str, device: torch.device) -> bool:
    """``inference.device_side`` (auto, true or false) for a model on ``device``: auto = CUDA only."""
    if not is_auto_bool(setting):
        raise ValueError(f"inference.device_side={short_repr(setting)}, expected auto, true or false")
    return device.type == "cuda" if setting == "auto" else bool(setting)


def _why_not_fused(device: torch.device, backbone: torch.nn.Module | None, bf16: bool, compile: bool) -> str:
    """Why the fused form cannot run here ('' when it can)."""
    from opnet.models.densenet import DenseNetBC

    if device.type != "cpu":
        return f"the fused form is for the CPU, not {device.type}"
    if bf16:
        return "the fused form computes in float32 (inference.precision=32)"
    if compile:
        return "the fused form is not compiled (torch.compile fuses the plain network itself)"
    if backbone is not None and not isinstance(backbone, DenseNetBC):
        return f"the fused form covers DenseNetBC, not {type(backbone).__name__}"
    return ""


def fast_forward(backbone: torch.nn.Module, settings: InferenceSettings) -> Callable[[torch.Tensor], torch.Tensor]:
    """A function (B, 1, S, S) -> fp32 output running ``backbone`` (in eval mode) the fast way.

    The fused form is built from the backbone's weights now: later changes to them are not seen.
    """
    device = next(backbone.parameters()).device
    graphed = settings.graphed(device)
    if settings.cuda_graph is True and not graphed:
        log.warning("inference.cuda_graph=true: %s; batch-1 forwards run without a CUDA graph",
                    "compiled forwards are not captured" if settings.compile else f"no CUDA device ({device.type})")
    elif settings.cuda_graph == "auto" and device.type != "cuda":
        log.info("inference: no CUDA device (%s), batch-1 forwards run without a CUDA graph", device.type)
    one, step, fused = _chunk_forward(backbone, settings, graphed)
    workers = settings.threads(fused)
    graph = CudaGraphForward(one) if graphed else None

    @torch.inference_mode()
    def run(images: torch.Tensor) -> torch.Tensor:
        x = images.to(device)
        if graph is not None and len(x) == 1:
            return graph(x)
        chunks = [x[i : i + step] for i in range(0, len(x), step)]
        if len(chunks) == 1:
            return one(x).contiguous()
        if workers > 1 and device.type == "cpu":
            outs = _on_workers(one, chunks, workers)
        else:
            outs = [one(c) for c in chunks]
        return torch.cat(outs).contiguous()

    return run


def _chunk_forward(backbone: torch.nn.Module, settings: InferenceSettings,
                   capturable: bool) -> tuple[Callable[[torch.Tensor], torch.Tensor], int, bool]:  # fmt: skip
    """(the forward of one chunk, images per chunk, fused) for ``settings``; ``capturable``: no
    autocast weight cache (a CUDA-graph capture must not use it)."""
    device = next(backbone.parameters()).device
    bf16, cl, fused = settings.resolved(device, backbone)
    backbone.eval()
    module: Callable[[torch.Tensor], torch.Tensor]
    step = settings.chunk()
    if fused:
        from opnet.models.fused import FusedDenseNet

        module = FusedDenseNet(backbone)
        step = settings.chunk(module.block_bytes_per_image)
    else:
        if cl:
            backbone = backbone.to(memory_format=torch.channels_last)
        module = torch.compile(backbone) if settings.compile else backbone

    def one(x: torch.Tensor) -> torch.Tensor:
        if cl and not fused:
            x = x.contiguous(memory_format=torch.channels_last)
        if bf16:
            with torch.autocast(device.type, dtype=torch.bfloat16, cache_enabled=not capturable):
                return module(x).float()
        return module(x)

    return one, step, fused


class GraphedPipeline:
    """One depth image to its pose hypotheses, end to end on the model's device: the
    preprocessing (:func:`opnet.data.preprocess_torch.to_network_input`), the network and the
    decoding with averaging (:class:`opnet.parameterizations.dense_decoding.DenseDecoding`), every
    shape fixed, so on a CUDA device the three run as one CUDA graph (captured at the first call,
    then replayed: one launch for the whole image). The depth goes to the device through a pinned
    buffer, the result comes back as one table, and the host only projects the averaged rotations
    and orders the rows. The same hypotheses as ``predict.py``'s path of the same settings (tests).

    Args:
        backbone: the network (its weights as they are now, in eval mode).
        settings: the inference settings (precision, channels-last; ``cuda_graph`` false: no graph).
        param: the parameterization, with its decoding settings.
        camera: the camera of the depth images (every image the same size).
        size, fit, canvas: the framing, as :func:`opnet.data.preprocess.to_network_input`.
        graph: capture a CUDA graph (default: on a CUDA device unless ``settings.cuda_graph`` is false).
        fuse: ``torch.compile`` the preprocessing and the decoding (not the network): their hundreds
            of small operations fused into a few kernels, compiled at the first image.
    """

    def __init__(self, backbone: torch.nn.Module, settings: InferenceSettings, param: Any, camera: Any,
                 size: int = 128, fit: str = "pad", canvas: tuple[int, int, int] | None = None,
                 graph: bool | None = None, fuse: bool = False) -> None:  # fmt: skip
        from opnet.data.preprocess import square_canvas
        from opnet.parameterizations.dense_decoding import DenseDecoding

        self.device = next(backbone.parameters()).device
        self.graph_wanted = self.device.type == "cuda" and settings.cuda_graph is not False if graph is None else graph
        if self.graph_wanted and self.device.type != "cuda":
            raise ValueError(f"GraphedPipeline: a CUDA graph needs a CUDA device, the model is on {self.device.type}")
        self.forward = _chunk_forward(backbone, settings, capturable=True)[0]
        self.camera, self.size = camera, size
        self.canvas = canvas if canvas is not None else square_canvas(camera, fit)
        x0, y0, side = self.canvas
        self.net_camera = camera.cropped(x0, y0, side, side).resized(size, size)
        self.decoding = DenseDecoding(param, self.net_camera, 1, self.device)
        self._preprocess: Callable[[torch.Tensor], torch.Tensor] | None = None  # compiled, with ``fuse``
        self._decode: Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]] | None = None
        if fuse:  # the lazy tables (resize taps, group tensors) made first: the compiled code only reads them
            shape = (1, param.out_channels, param.grid_size, param.grid_size)
            with torch.no_grad():
                self._network_input(torch.zeros((1, camera.height, camera.width), device=self.device))
                self.decoding(torch.zeros(shape, device=self.device))
            # the resize tables come from a cache that Dynamo traces through: deterministic, so constants
            warnings.filterwarnings("ignore", message=r"Dynamo detected a call to a `functools.lru_cache`-wrapped "
                                    r"function at 'preprocess_torch.py", category=UserWarning)  # fmt: skip
            self._preprocess = torch.compile(self._network_input, dynamic=False)
            self._decode = torch.compile(self.decoding.__call__, dynamic=False)
        self._graph: Any = None
        shape = (1, camera.height, camera.width)
        self._depth = torch.zeros(shape, dtype=torch.float32, device=self.device)
        self._host_depth = torch.zeros(shape, dtype=torch.float32, pin_memory=self.graph_wanted)
        self._result: torch.Tensor | None = None
        self._output: torch.Tensor | None = None
        self._host_result: torch.Tensor | None = None

    @torch.no_grad()  # not inference mode: compiled code guards numpy attributes, which that mode upsets
    def compute(self, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(1, H, W) depth on the device -> (the flat float64 result: the decoding's table, then
        three flags: the clustering settled, the depth holds infinite values, the network's output
        is not finite; the network output). Nothing is read back: capturable."""
        output = self.forward((self._preprocess or self._network_input)(depth))
        table, settled = (self._decode or self.decoding)(output)
        flags = torch.stack((settled.all(), torch.isinf(depth).any(), ~torch.isfinite(output).all()))
        return torch.cat((table.reshape(-1), flags.to(torch.float64))), output

    def _network_input(self, depth: torch.Tensor) -> torch.Tensor:
        from opnet.data import preprocess_torch

        return preprocess_torch.to_network_input(depth, self.camera, self.size, canvas=self.canvas, static=True)[0]

    def __call__(self, depth: Any) -> Any:
        """Hypotheses (:class:`opnet.metrics.records.HypothesisSet`, camera frame, metres) of one
        (H, W) depth image in metres (NaN or z <= 0 = missing).

        Raises:
            ValueError: an image that is no float (H, W) array of the camera's size, infinite depth,
                or a network output that is not finite.
        """
        import numpy as np

        from opnet.data.preprocess import _check_matches_camera

        if not isinstance(depth, np.ndarray) or depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"depth: expected an (H, W) float numpy image, got "
                             f"{getattr(depth, 'shape', type(depth).__name__)} {getattr(depth, 'dtype', '')}")
        _check_matches_camera(depth, self.camera, "depth")
        self._host_depth[0].numpy()[...] = depth
        if self.graph_wanted:
            result, output = self._replay()
        else:
            self._depth.copy_(self._host_depth)
            result, output = self.compute(self._depth)
            result = result.cpu()
        values = result.numpy()
        settled, infinite, diverged = values[-3:] > 0.5
        if infinite:
            raise ValueError("depth: contains infinite values; use NaN for missing depth")
        if diverged:
            raise ValueError("the network's output holds NaN or inf (diverged weights or an input it cannot take)")
        table = values[:-3].reshape(1, self.decoding.cells, -1)
        return self.decoding.hypotheses(table, np.array([settled]), output)[0]

    def _replay(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self._graph is None:
            self._capture()
        self._depth.copy_(self._host_depth, non_blocking=True)
        self._graph.replay()
        self._host_result.copy_(self._result, non_blocking=True)
        torch.cuda.current_stream(self.device).synchronize()
        return self._host_result, self._output

    def _capture(self) -> None:
        self._depth.copy_(self._host_depth)
        self._graph, (self._result, self._output) = capture_graph(lambda: self.compute(self._depth), self.device)
        self._host_result = torch.empty_like(self._result, device="cpu").pin_memory()


def capture_graph(fn: Callable[[], Any], device: torch.device) -> tuple[Any, Any]:
    """``(graph, outputs)``: ``fn`` captured as a CUDA graph on ``device`` after three warm-up calls on
    a side stream (lazy tables, cuBLAS handles and the allocator's blocks made outside the capture);
    ``outputs`` are the graph's own buffers, refilled by every ``graph.replay()``."""
    side = torch.cuda.Stream(device)
    side.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(side):
        for _ in range(3):
            fn()
    torch.cuda.current_stream(device).wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        outputs = fn()
    return graph, outputs


class CudaGraphForward:
    """A forward function replayed as a CUDA graph: captured at the first call of each input shape
    (after three warm-up calls on a side stream), then the input is copied into the graph's own
    buffer and the graph replayed; returns a copy of the graph's output buffer."""

    def __init__(self, forward: Callable[[torch.Tensor], torch.Tensor]) -> None:
        self.forward = forward
        self.graphs: dict[tuple[int, ...], tuple[Any, torch.Tensor, torch.Tensor]] = {}

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        key = tuple(x.shape)
        if key not in self.graphs:
            self.graphs[key] = self._capture(x)
        graph, static_in, static_out = self.graphs[key]
        static_in.copy_(x)
        graph.replay()
        return static_out.clone()

    def _capture(self, x: torch.Tensor) -> tuple[Any, torch.Tensor, torch.Tensor]:
        static_in = x.clone()
        graph, static_out = capture_graph(lambda: self.forward(static_in), x.device)
        return graph, static_in, static_out


def _on_workers(fn: Callable[[torch.Tensor], torch.Tensor], chunks: list[torch.Tensor], workers: int) -> list[torch.Tensor]:
    """``[fn(c) for c in chunks]`` on ``workers`` threads at once, each computing with one core
    (the first error is raised after all threads have ended)."""
    import threading

    outs: list[torch.Tensor | None] = [None] * len(chunks)
    errors: list[BaseException] = []
    main_threads = torch.get_num_threads()

    def work(first: int) -> None:
        torch.set_num_threads(1)  # this thread's own OpenMP / MKL setting
        try:
            with torch.inference_mode():
                for i in range(first, len(chunks), workers):
                    outs[i] = fn(chunks[i])
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,), daemon=True) for k in range(min(workers, len(chunks)))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    torch.set_num_threads(main_threads)  # the default for threads started later, as before
    if errors:
        raise errors[0]
    return outs  # type: ignore[return-value]
