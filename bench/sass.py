#!/usr/bin/env python3
"""The machine code (SASS) NVIDIA's Vulkan driver made of the kernels, from its shader disk cache.

Run a render on the GPU machine with the driver's cache in a folder of its own,

    __GL_SHADER_DISK_CACHE=1 __GL_SHADER_DISK_CACHE_PATH=/tmp/c \
    __GL_SHADER_DISK_CACHE_SKIP_CLEANUP=1 raytrace render bunny --spp 1 ...

bring the folder back (tar it under $OUT), and here

    python3 bench/sass.py CACHE_DIR OUT_DIR [SM90]

writes OUT_DIR/pipeline-K.sass for every pipeline the cache holds (K in the cache's order; the
path tracer is the largest), disassembled by `nvdisasm` (PyPI: `pip download
nvidia-cuda-nvdisasm`, unzip, `NVDISASM=.../nvidia/cu13/bin/nvdisasm`; `pip install zstandard`).

The cache's `.bin` files hold one zstd frame per pipeline; each frame is the driver's own
container (it starts `NVDANVVMNVuc`), whose code is raw SASS at some offset: the first offset
(8 bytes apart) past the frame's header from which 64 instructions decode. The code ends
where decoding fails (`raytrace info --kernels` or `RT_STATS`-style statistics give its exact
"Binary Size"). Not a supported interface of the driver: it may change with any release
(read with driver 580.159.04, bench/NOTES.md session 53).
"""
import glob
import os
import re
import subprocess
import sys

import zstandard

NVDISASM = os.environ.get("NVDISASM", "nvdisasm")


def disassemble(code, arch):
    path = "/tmp/_sass_probe.bin"
    with open(path, "wb") as f:
        f.write(code)
    r = subprocess.run([NVDISASM, "-b", arch, path], capture_output=True, text=True)
    return "error" not in r.stdout + r.stderr, r.stdout


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    cache, out, arch = sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else "SM90"
    os.makedirs(out, exist_ok=True)
    k = 0
    for path in sorted(glob.glob(os.path.join(cache, "**", "*.bin"), recursive=True)):
        data = open(path, "rb").read()
        for m in re.finditer(re.escape(b"\x28\xb5\x2f\xfd"), data):
            frame = zstandard.ZstdDecompressor().decompressobj().decompress(data[m.start():])
            start = next(
                (x for x in range(16, min(len(frame), 8192), 8) if disassemble(frame[x : x + 16 * 64], arch)[0]),
                None,
            )
            if start is None:
                continue
            # The longest prefix that decodes (a prefix of one that decodes decodes too).
            lo, hi = 64, (len(frame) - start) // 16 + 1
            while hi - lo > 1:
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if disassemble(frame[start : start + 16 * mid], arch)[0] else (lo, mid)
            _, text = disassemble(frame[start : start + 16 * lo], arch)
            lines = [l for l in text.splitlines() if re.match(r"\s+/\*[0-9a-f]{4,}\*/", l)]
            name = os.path.join(out, f"pipeline-{k}.sass")
            with open(name, "w") as f:
                f.write("\n".join(lines) + "\n")
            print(f"{name}: {len(lines)} instructions decoded (frame of {len(frame)} bytes, code at {start})")
            k += 1


if __name__ == "__main__":
    main()
