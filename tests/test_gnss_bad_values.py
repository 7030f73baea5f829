"""CRC-valid NovAtel messages with bad contents: non-ASCII bytes, NaN/inf or out-of-range values
(issue 21, defects 5 and 12). Messages are built in tests/novatel_frames.py."""

import struct

import pytest
from novatel_frames import (
    SECONDS,
    WEEK,
    ascii_line,
    bestpos_body,
    binary_frame,
    inspva_body,
    inspva_line,
    inspvax_body,
    inspvax_body_fields,
)

from lidar3d.config import GnssConfig
from lidar3d.errors import GnssError
from lidar3d.gnss import parse_span_bytes, span_reference
from lidar3d.gnss.ascii_log import MessageRejected, decode_ascii_message
from lidar3d.gnss.binary_log import decode_binary_frame


def test_non_ascii_byte_in_a_crc_valid_line_is_a_gnss_error():
    line = inspva_line(lat="48.1\xe97")  # latin-1 e-acute, CRC computed over it
    with pytest.raises(GnssError, match=r"^INSPVAA: non-ASCII byte 0xe9 at column \d+$") as info:
        decode_ascii_message(line)
    assert info.value.kind == "format"


def test_non_ascii_byte_in_the_name_names_what_it_can():
    line = ascii_line("#", "INS\xffPVAA,COM1,0,70.0,FINESTEERING,2300,300000.000,02000020,54e2,16809", "1,2")
    with pytest.raises(GnssError, match=r"^INS\ufffdPVAA: non-ASCII byte 0xff at column 5$"):
        decode_ascii_message(line)


@pytest.mark.parametrize(
    "fields,message",
    [
        ({"lat": "nan"}, r"latitude_deg nan is not finite"),
        ({"lat": "91.5"}, r"latitude_deg 91.5 outside \[-90, 90\]"),
        ({"lon": "-inf"}, r"longitude_deg -inf is not finite"),
        ({"lon": "180.01"}, r"longitude_deg 180.01 outside \[-180, 180\]"),
        ({"h": "inf"}, r"height_ellipsoid_m inf is not finite"),
        ({"h": "25000.0"}, r"height_ellipsoid_m 25000.0 outside \[-1000, 20000\] m"),
        ({"h": "-1500.0"}, r"height_ellipsoid_m -1500.0 outside"),
    ],
)
def test_ascii_inspva_with_bad_position_is_rejected(fields, message):
    with pytest.raises(MessageRejected, match=f"^INSPVAA: {message}") as info:
        decode_ascii_message(inspva_line(**fields))
    assert info.value.kind == "range"


def test_ascii_velocity_attitude_and_time_must_be_finite():
    body = f"{WEEK},{SECONDS:.3f},48.1,11.5,500.0,nan,5.0,0.0,0.5,-0.3,45.0,INS_SOLUTION_GOOD"
    line = ascii_line("%", f"INSPVASA,{WEEK},{SECONDS:.3f}", body)
    with pytest.raises(MessageRejected, match=r"^INSPVASA: north_velocity_mps nan is not finite$"):
        decode_ascii_message(line)
    body = f"{WEEK},{SECONDS:.3f},48.1,11.5,500.0,0.0,5.0,0.0,0.5,-0.3,inf,INS_SOLUTION_GOOD"
    with pytest.raises(MessageRejected, match="azimuth_deg inf is not finite"):
        decode_ascii_message(ascii_line("%", f"INSPVASA,{WEEK},{SECONDS:.3f}", body))
    body = f"{WEEK},nan,48.1,11.5,500.0,0.0,5.0,0.0,0.5,-0.3,45.0,INS_SOLUTION_GOOD"
    with pytest.raises(MessageRejected, match=r"GPS seconds nan outside \[0, 604800\)"):
        decode_ascii_message(ascii_line("%", f"INSPVASA,{WEEK},{SECONDS:.3f}", body))
    header = f"INSPVAXA,COM1,0,60.5,FINESTEERING,{10**25},{SECONDS:.3f},02000020,46eb,16809"
    with pytest.raises(MessageRejected, match=r"GPS week 10{25} outside \[0, 9999\]"):
        decode_ascii_message(ascii_line("#", header, ",".join(inspvax_body_fields())))


def test_ascii_inspvax_height_is_msl_plus_undulation_checked():
    header = f"INSPVAXA,COM1,0,60.5,FINESTEERING,{WEEK},{SECONDS:.3f},02000020,46eb,16809"
    line = ascii_line("#", header, ",".join(inspvax_body_fields(undulation="nan")))
    with pytest.raises(MessageRejected, match=r"^INSPVAXA: height_ellipsoid_m nan is not finite$"):
        decode_ascii_message(line)


def test_placeholder_position_of_an_aligning_ins_is_kept_as_decoded():
    # a ProPak6 prints the Earth's centre while aligning; the INS status filter drops it later
    fields = inspvax_body_fields(lat="-90.0", lon="0.0", h_msl="-6356752.3142", undulation="0.0")
    fields[0:2] = ["INS_ALIGNING", "NONE"]
    header = f"INSPVAXA,COM1,0,60.5,FINESTEERING,{WEEK},{SECONDS:.3f},02000020,46eb,16809"
    _name, message = decode_ascii_message(ascii_line("#", header, ",".join(fields)))
    assert message.height_ellipsoid_m == pytest.approx(-6356752.3142)


@pytest.mark.parametrize(
    "message_id,body,message",
    [
        (507, inspva_body(lat=float("nan")), "INSPVA: latitude_deg nan is not finite"),
        (507, inspva_body(roll=float("inf")), "INSPVA: roll_deg inf is not finite"),
        (1465, inspvax_body(lat=-90.5), r"INSPVAX: latitude_deg -90.5 outside \[-90, 90\]"),
        (1465, inspvax_body(h_msl=float("inf")), "INSPVAX: height_ellipsoid_m inf is not finite"),
        (42, bestpos_body(lon=361.0), r"BESTPOS: longitude_deg 361.0 outside \[-180, 180\]"),
        (507, inspva_body(seconds=604800.5), r"INSPVA: GPS seconds 604800.5 outside \[0, 604800\)"),
    ],
    ids=["inspva-nan-lat", "inspva-inf-roll", "inspvax-lat", "inspvax-inf-h", "bestpos-lon", "inspva-seconds"],
)
def test_binary_frames_with_bad_values_are_rejected(message_id, body, message):
    with pytest.raises(MessageRejected, match=f"^{message}$") as info:
        decode_binary_frame(binary_frame(message_id, body))
    assert info.value.kind == "range"


def test_binary_frame_whose_length_disagrees_with_its_header_is_rejected():
    frame = binary_frame(507, inspva_body())
    with pytest.raises(MessageRejected, match=r"binary frame of 100 bytes, its header says 120"):
        decode_binary_frame(frame[:100])
    with pytest.raises(MessageRejected, match="does not start with a NovAtel sync"):
        decode_binary_frame(b"\x00" + frame[1:])


def test_reader_counts_and_skips_bad_values_and_reference_uses_the_good_ones():
    good = [inspva_line(seconds=SECONDS + 0.05 * k) for k in range(1, 11)]
    bad_first = inspva_line(lat="nan", seconds=SECONDS)  # the first fix: it must not become the origin
    bad_binary = binary_frame(507, inspva_body(h=float("inf"), seconds=SECONDS + 0.6))
    data = b"\r\n".join([bad_first, *good]) + b"\r\n" + bad_binary
    log = parse_span_bytes(data, source="span.log")
    stats = log.stats
    assert (stats.out_of_range, stats.bad_format, stats.bad_crc) == (2, 0, 0)
    assert stats.rejected == 2 and len(log.ins) == 10
    assert stats.problems[0] == "line 1: INSPVAA: latitude_deg nan is not finite"
    assert "2 with non-finite or out-of-range values" in stats.summary()
    reference = span_reference(log, GnssConfig())
    assert reference.origin.latitude_deg == pytest.approx(48.137)


def test_reference_never_takes_a_placeholder_position_as_origin():
    fields = inspvax_body_fields(lat="-90.0", lon="0.0", h_msl="-6356752.3142", undulation="0.0")
    fields[0:2] = ["INS_ALIGNING", "NONE"]
    header = f"INSPVAXA,COM1,0,60.5,FINESTEERING,{WEEK},{SECONDS:.3f},02000020,46eb,16809"
    log = parse_span_bytes(ascii_line("#", header, ",".join(fields)) + b"\r\n")
    config = GnssConfig(accepted_ins_statuses=("INS_SOLUTION_GOOD", "INS_ALIGNING"))
    with pytest.raises(GnssError, match="no accepted INSPVAX solution has a usable position"):
        span_reference(log, config)


def test_struct_layout_of_the_test_encoder_matches_the_body_lengths():
    assert len(inspva_body()) == 88 and len(inspvax_body()) == 126 and len(bestpos_body()) == 72
    assert struct.calcsize("<3sBHBBHHBBHIIHH") == 28
