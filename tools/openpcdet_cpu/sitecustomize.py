"""Run OpenPCDet's own, unmodified tools on a machine without CUDA, to check the launcher against real OpenPCDet.

Not part of the package and not for production: a GPU machine with OpenPCDet built needs none of this. With this
folder first on PYTHONPATH, Python imports this file at start-up (site's sitecustomize hook); it changes nothing in
OpenPCDet or in site-packages. What a CPU lacks, and what stands in for it:
1. OpenPCDet's compiled extensions (pcdet.ops.*.*_cuda, bev_pool_ext), imported at module level by pcdet.models and
   pcdet.datasets: stand-in modules. iou3d_nms_cuda's nms_gpu / nms_normal_gpu (post-processing) and
   boxes_overlap_bev_gpu / boxes_iou_bev_gpu (the recall record of test.py) run on the CPU with the project's rotated
   geometry; any other op raises a RuntimeError naming it when called (SECOND calls none).
2. `.cuda()` on tensors and modules (model.cuda(), load_data_to_gpu, anchors, code weights): returns self.
3. torch.cuda.FloatTensor(size), with which iou3d_nms_utils allocates its outputs: a CPU float tensor.
4. torchvision (PyPI has only CUDA builds, whose ops do not register on torch+cpu), imported by OpenPCDet for image
   models only: a stand-in module whose attributes raise when used.
5. spconv's CPU backward asks torch.cuda for a stream: the project's spconv patch (models.spconv_cpu.patch_spconv).
Run with OMP_NUM_THREADS=1 (spconv's CPU scatter-add is wrong with more threads). Steps: docs/getting_started.md.
"""
import importlib.abc
import importlib.machinery
import sys

COMPILED = {"iou3d_nms_cuda", "roiaware_pool3d_cuda", "roipoint_pool3d_cuda", "pointnet2_stack_cuda",
            "pointnet2_batch_cuda", "bev_pool_ext", "ingroup_inds_cuda"}


def _missing(module: str, attribute: str):
    def call(*args, **kwargs):
        raise RuntimeError(f"{module}.{attribute} is a compiled CUDA op of OpenPCDet with no CPU stand-in here "
                           f"(tools/openpcdet_cpu/sitecustomize.py)")
    return call


def _iou3d_nms_on_cpu(module) -> None:
    """iou3d_nms_cuda's four ops as OpenPCDet's iou3d_nms_utils calls them (outputs written into given tensors)."""
    import torch

    from pcdet_memslidar.geometry.iou import bev_intersection_area, boxes_iou_bev, near_pairs
    from pcdet_memslidar.geometry.nms import nms_rotated

    def greedy(boxes, keep, thresh, axis_aligned):
        boxes = boxes.detach().cpu().float()[:, :7].clone()
        if axis_aligned:
            boxes[:, 6] = 0.0
        ranks = -torch.arange(len(boxes), dtype=torch.float32)  # OpenPCDet sorts by score before the op
        kept = nms_rotated(boxes, ranks, float(thresh)) if len(boxes) else torch.zeros(0, dtype=torch.long)
        keep[:len(kept)] = kept.to(keep.dtype)
        return len(kept)

    def overlap(boxes_a, boxes_b):
        a, b = boxes_a.detach().cpu()[:, :7], boxes_b.detach().cpu()[:, :7]
        area = torch.zeros((len(a), len(b)), dtype=torch.float64)
        if len(a) and len(b):
            rows, cols = near_pairs(a, b)
            area[rows, cols] = bev_intersection_area(a[rows], b[cols])
        return area

    def boxes_iou_bev_gpu(boxes_a, boxes_b, ans_iou):
        iou = boxes_iou_bev(*(boxes.detach().cpu()[:, :7].double().numpy() for boxes in (boxes_a, boxes_b)))
        ans_iou.copy_(torch.from_numpy(iou).to(ans_iou.dtype))

    module.nms_gpu = lambda boxes, keep, thresh: greedy(boxes, keep, thresh, axis_aligned=False)
    module.nms_normal_gpu = lambda boxes, keep, thresh: greedy(boxes, keep, thresh, axis_aligned=True)
    module.boxes_overlap_bev_gpu = lambda a, b, ans: ans.copy_(overlap(a, b).to(ans.dtype))
    module.boxes_iou_bev_gpu = boxes_iou_bev_gpu


class _StandIn(importlib.abc.Loader):
    """A module whose every attribute is an op that raises; iou3d_nms_cuda gets its four CPU ops."""

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        def __getattr__(attribute, _name=module.__name__):
            if attribute.startswith("__"):
                raise AttributeError(attribute)
            return _missing(_name, attribute)

        module.__getattr__ = __getattr__
        if module.__name__.endswith(".iou3d_nms_cuda"):
            _iou3d_nms_on_cpu(module)


class _StandInFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.startswith("pcdet.ops.") and fullname.rsplit(".", 1)[-1] in COMPILED:
            return importlib.machinery.ModuleSpec(fullname, _StandIn())
        if fullname == "torchvision" and not any(
                finder.find_spec(fullname, None) for finder in sys.meta_path
                if finder is not self and hasattr(finder, "find_spec")):
            return importlib.machinery.ModuleSpec(fullname, _StandIn())
        return None


def _torch_on_cpu() -> None:
    from pcdet_memslidar.policy import apply_process_policy

    apply_process_policy()  # first: libgomp reads OpenMP's wait hint when torch loads it
    import torch

    from pcdet_memslidar.models.spconv_cpu import patch_spconv

    if torch.cuda.is_available():
        return
    torch.Tensor.cuda = lambda self, *args, **kwargs: self
    torch.nn.Module.cuda = lambda self, *args, **kwargs: self
    torch.cuda.FloatTensor = lambda *size: torch.zeros(*size, dtype=torch.float32)
    patch_spconv()


sys.meta_path.insert(0, _StandInFinder())
_torch_on_cpu()
