"""NovAtel CRC-32: reflected polynomial 0xEDB88320, initial value 0, no final XOR.

NovAtel's ``CalculateBlockCRC32`` differs from ``zlib.crc32`` only in its initial value and final
XOR, so ``zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF`` computes it (checked against the real logs in
``shared/data/real/novatel_ascii``). ASCII logs carry it over the characters strictly between the
leading ``#``/``%`` and the ``*``; binary logs over header and body, appended little-endian.
"""

from __future__ import annotations

import zlib

__all__ = ["novatel_crc32"]


def novatel_crc32(data: bytes) -> int:
    """NovAtel block CRC-32 of ``data``."""
    return zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF
