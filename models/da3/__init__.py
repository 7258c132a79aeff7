"""Depth Anything 3 through ONNX Runtime: graph contract, preprocessing, metric scale, runtime."""

from models.da3.contract import CONTRACT, CONTRACT_VERSION, check_da3_signature, da3_resolution
from models.da3.runtime import OnnxDA3

__all__ = ["CONTRACT", "CONTRACT_VERSION", "OnnxDA3", "check_da3_signature", "da3_resolution"]
