#!/usr/bin/python3
"""The .rays file of docs/RAYSETS.md, as the measurement scripts read it: a 16-byte header
("RAYS", uint32 version 1, uint64 ray count, little-endian), then 32 bytes a ray. Standard library
only. Imported by sort-rays.py (`read`); run by instr-count.sh and ray-cost-split.sh:

    /usr/bin/python3 scripts/rays_file.py count FILE                 # prints the ray count
    /usr/bin/python3 scripts/rays_file.py cut SRC DST FIRST N        # rays [FIRST, FIRST+N) to DST

A file that is not a whole version-1 .rays file, or a cut outside it, stops the script with a
message naming the file.
"""
import struct
import sys

MAGIC = b"RAYS"
VERSION = 1
HEADER_BYTES = 16
RAY_BYTES = 32


class RaysFileError(Exception):
    pass


def header(raw, path):
    """The ray count of a .rays file whose bytes (or first bytes) are raw."""
    if len(raw) < HEADER_BYTES or raw[:4] != MAGIC:
        raise RaysFileError(f"{path} is not a .rays file (no RAYS header)")
    version, count = struct.unpack("<IQ", raw[4:HEADER_BYTES])
    if version != VERSION:
        raise RaysFileError(f"{path} is a .rays file of version {version}, not {VERSION}")
    return count


def pack_header(count):
    return MAGIC + struct.pack("<IQ", VERSION, count)


def checked_count(head, size, path):
    """The ray count of a .rays file of `size` bytes that starts with `head`, checked against
    its size."""
    n = header(head, path)
    if size != HEADER_BYTES + RAY_BYTES * n:
        raise RaysFileError(
            f"{path} holds {size} bytes, not the {HEADER_BYTES + RAY_BYTES * n} of {n} rays")
    return n


def count(path):
    """The ray count of the .rays file at path, checked against its size."""
    with open(path, "rb") as f:
        head = f.read(HEADER_BYTES)
        return checked_count(head, f.seek(0, 2), path)


def read(path):
    """The ray count and the whole bytes of the .rays file at path (read once, checked)."""
    with open(path, "rb") as f:
        raw = f.read()
    return checked_count(raw[:HEADER_BYTES], len(raw), path), raw


def cut(src, dst, first, n):
    """Writes rays [first, first + n) of src to dst as a .rays file of its own."""
    total = count(src)
    if first < 0 or n < 0 or first + n > total:
        raise RaysFileError(f"{src}: rays [{first}, {first + n}) lie outside its {total} rays")
    with open(src, "rb") as f:
        f.seek(HEADER_BYTES + RAY_BYTES * first)
        body = f.read(RAY_BYTES * n)
    with open(dst, "wb") as f:
        f.write(pack_header(n))
        f.write(body)


def main(argv):
    try:
        if len(argv) == 2 and argv[0] == "count":
            print(count(argv[1]))
        elif len(argv) == 5 and argv[0] == "cut":
            cut(argv[1], argv[2], int(argv[3]), int(argv[4]))
        else:
            sys.exit(__doc__)
    except (RaysFileError, OSError, ValueError) as e:
        sys.exit(f"rays_file: {e}")


if __name__ == "__main__":
    main(sys.argv[1:])
