"""The NVIDIA GPUs of this machine and their memory, as `nvidia-smi` reports them (for `davio info`).

Read-only and optional: a machine without `nvidia-smi` (a CPU machine, a Jetson, whose tool is
tegrastats) gets an empty list and the reason. Memory in MiB, as nvidia-smi counts it; what the GPU
holds for other programs is what `--gpu-mem-limit` has to leave free.
"""

from __future__ import annotations

import shutil
import subprocess

QUERY = "index,name,memory.total,memory.used"


def gpu_inventory(timeout_s: float = 5.0) -> tuple[list[dict], str]:
    """([{index, name, memory_total_mib, memory_used_mib}, ...], a note: '' or why the list is short)."""
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return [], "nvidia-smi not found"
    try:
        done = subprocess.run([exe, f"--query-gpu={QUERY}", "--format=csv,noheader,nounits"],
                              capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        return [], f"nvidia-smi did not answer within {timeout_s:g} s"
    except OSError as exc:
        return [], f"nvidia-smi could not run ({exc.strerror or exc})"
    if done.returncode != 0:
        why = (done.stderr or done.stdout).strip().splitlines()
        return [], f"nvidia-smi failed (exit {done.returncode}): {why[0] if why else 'no message'}"
    gpus, bad = [], 0
    for line in done.stdout.splitlines():
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]   # a name may hold commas: it is the middle
        try:
            if len(fields) < 4:
                raise ValueError(line)
            index, total, used = int(fields[0]), int(fields[-2]), int(fields[-1])
        except ValueError:   # e.g. "[N/A]" memory on a GPU in a bad state
            bad += 1
            continue
        gpus.append({"index": index, "name": ", ".join(fields[1:-2]), "memory_total_mib": total,
                     "memory_used_mib": used})
    note = f"{bad} line(s) of nvidia-smi not understood" if bad else ""
    if not gpus and not note:
        note = "nvidia-smi lists no GPU"
    return gpus, note
