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


def move_into_place(written: Path, out: Path) -> None:
    """Move the graph file `written` (and the external data file its tensors name, if any) to `out` and
    `data_path(out)`; a `data_path(out)` left by an earlier graph is removed when this one has none.

    Raises:
        ModelError: the graph's tensors name more than one data file, or one outside its folder.
    """
    import onnx

    model = onnx.load(str(written), load_external_data=False)
    tensors = _external(model)
    locations = {e.value for t in tensors for e in t.external_data if e.key == "location"}
    data = data_path(out)
    if len(locations) > 1:
        raise ModelError(f"{written}: its weights are spread over {len(locations)} files; one was expected")
    if locations:
        source = written.parent / locations.pop()
        if source.resolve().parent != written.resolve().parent:
            raise ModelError(f"{written}: its weights lie outside its folder ({source})")
        for tensor in tensors:
            for entry in tensor.external_data:
                if entry.key == "location":
                    entry.value = data.name
        onnx.save(model, str(written))    # the graph only: its tensors stay in the data file
        os.replace(source, data)
    else:
        data.unlink(missing_ok=True)
    os.replace(written, out)


def save_graph(model, out: Path, external: bool) -> None:
    """Write `model` (an onnx.ModelProto; its tensors are moved out of it when `external`) to `out`, with
    its weights in `data_path(out)` when `external`. The file appears under its name only once written."""
    import onnx

    tmp = temporary_path(out)
    if external:
        tmp_data = data_path(tmp)
        tmp_data.unlink(missing_ok=True)    # onnx.save appends to an existing data file
        onnx.save(model, str(tmp), save_as_external_data=True, all_tensors_to_one_file=True,
                  location=tmp_data.name)
    else:
        onnx.save(model, str(tmp))
    move_into_place(tmp, out)


def remove_graph(out: Path) -> None:
    """Remove the graph at `out`, its data file, its model card (`.json`) and any temporary file of them."""
    tmp = temporary_path(out)
    for path in (out, data_path(out), out.with_suffix(".json"), tmp, data_path(tmp)):
        path.unlink(missing_ok=True)
