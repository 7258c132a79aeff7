"""Writing exported ONNX graphs: under a temporary name first, then moved into place; the weights of a
graph too large for one protobuf message (2 GiB) go to one external data file `<graph>.data` beside it.

onnx appends to an existing data file and torch's exporter names the data after the file it writes, so
both writers go through `move_into_place`, which gives the data its final name and removes a stale one.
"""

from __future__ import annotations

import os
from pathlib import Path

from models.onnx_file import all_tensors
from runtime.errors import ModelError

#: weights over this many bytes go to `<graph>.data` (protobuf refuses messages over 2 GiB)
EXTERNAL_DATA_BYTES = 1.8e9


def data_path(graph: Path) -> Path:
    """Where the external data of the graph at `graph` lives: `<graph>.data`."""
    return graph.with_name(graph.name + ".data")


def temporary_path(graph: Path) -> Path:
    """The name a graph is written under before `move_into_place` (beside it: the same file system)."""
    return graph.with_name(graph.name + ".tmp")


def _external(model) -> list:
    from onnx import TensorProto

    return [t for t in all_tensors(model) if t.data_location == TensorProto.EXTERNAL]


def weights_bytes(model) -> int:
    """Bytes of the tensors `model` holds in itself (its weights; external data not counted)."""
    return sum(t.ByteSize() for t in all_tensors(model))


def move_into_place(written: Path, out: Path) -> None:
    """Move the graph file `written` (and the external data file its tensors name, if any) to `out` and
    `data_path(out)`; a `data_path(out)` left by an earlier graph is removed when this one has none (after
    the graph is in place). With external data the data file is moved first: an interruption between the
    two moves leaves the earlier graph beside the new weights (its check against them then fails).

    Raises:
        ModelError: the graph's tensors name more than one data file, one not beside it, or one that
            is missing.
    """
    import onnx

    model = onnx.load(str(written), load_external_data=False)
    tensors = _external(model)
    locations = {os.path.normpath(e.value) for t in tensors for e in t.external_data if e.key == "location"}
    data = data_path(out)
    if not locations:
        os.replace(written, out)
        data.unlink(missing_ok=True)
        return
    if len(locations) > 1:
        raise ModelError(f"{written}: its weights are spread over {len(locations)} files; one was expected")
    source = written.parent / locations.pop()
    if source.resolve().parent != written.resolve().parent:
        raise ModelError(f"{written}: its weights are not beside it ({source})")
    if not source.is_file():
        raise ModelError(f"{written}: the file holding its weights, {source.name}, is missing")
    for tensor in tensors:
        for entry in tensor.external_data:
            if entry.key == "location":
                entry.value = data.name
    onnx.save(model, str(written))    # the graph only: its tensors stay in the data file
    os.replace(source, data)
    os.replace(written, out)


def save_graph(model, out: Path, external: bool | None = None) -> None:
    """Write `model` (an onnx.ModelProto; its tensors are moved out of it when external) to `out`, with its
    weights in `data_path(out)` when `external` (None: when they exceed EXTERNAL_DATA_BYTES). The file
    appears under its name only once written; a failed write leaves no temporary file."""
    import onnx

    if external is None:
        external = weights_bytes(model) > EXTERNAL_DATA_BYTES
    tmp = temporary_path(out)
    try:
        if external:
            tmp_data = data_path(tmp)
            tmp_data.unlink(missing_ok=True)    # onnx.save appends to an existing data file
            onnx.save(model, str(tmp), save_as_external_data=True, all_tensors_to_one_file=True,
                      location=tmp_data.name)
            move_into_place(tmp, out)
        else:
            onnx.save(model, str(tmp))
            os.replace(tmp, out)
            data_path(out).unlink(missing_ok=True)   # an earlier graph's weights
    except BaseException:
        remove_temporary(out)
        raise


def remove_temporary(out: Path) -> None:
    """Remove the temporary files of a graph being written to `out` (`temporary_path` and its data)."""
    tmp = temporary_path(out)
    for path in (tmp, data_path(tmp)):
        path.unlink(missing_ok=True)


def remove_graph(out: Path) -> None:
    """Remove the graph at `out`, its data file, its model card (`.json`) and any temporary file of them."""
    for path in (out, data_path(out), out.with_suffix(".json")):
        path.unlink(missing_ok=True)
    remove_temporary(out)
