"""The survey writers in their sink homes: `sinks.jsonl` (the survey log) and `sinks.rosbag`
(a ROS 2 bag), both reading their log lines from the helper `sinks.log_lines`."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from agrislam.config import FieldSchema
from agrislam.io.ros.conventions import META_TOPIC, TRUTH_TOPIC
from agrislam.io.ros.messages import DETECTION3D_ARRAY, ODOMETRY, STRING
from agrislam.io.sinks import jsonl as jsonl_sink
from agrislam.io.sinks import log_lines
from agrislam.io.sinks.jsonl import LogWriter, write_log
from agrislam.io.sinks.rosbag import write_survey_bag
from agrislam.records import (
    Detection,
    Detections,
    DiscreteMeasurement,
    Meta,
    Odometry,
    Record,
    TruthObject,
    TruthPose,
)


def survey() -> list[Record]:
    schema = FieldSchema.preset("crops_weeds")
    return [
        Meta(schema=schema),
        TruthObject("a", np.array([1.0, 2.0]), {"type": "crop", "size": "small"}),
        TruthPose(0.0, "r1", np.zeros(3)),
        Odometry(0.0, "r1", pose=np.zeros(3), cov=np.diag([1e-4, 1e-4, 1e-5])),
        Detections(
            0.0,
            "r1",
            (
                Detection(
                    xy=np.array([1.0, 0.5]), attributes={"type": DiscreteMeasurement("crop", 0.8)}
                ),
            ),
            "front",
        ),
    ]


def test_the_jsonl_sink_writes_what_log_lines_encodes(tmp_path: Path):
    assert jsonl_sink.record_to_json is log_lines.record_to_json
    records = survey()
    with LogWriter(tmp_path / "s.jsonl.gz") as writer:
        for record in records:
            writer.write(record)
        assert writer.lines == len(records)
    with gzip.open(tmp_path / "s.jsonl.gz", "rt", encoding="utf-8") as f:
        lines = f.read().splitlines()
    assert [json.loads(line) for line in lines] == [log_lines.record_to_json(r) for r in records]
    assert write_log(iter(records), tmp_path / "s.jsonl") == len(records)
    assert (tmp_path / "s.jsonl").read_text().splitlines() == lines


def test_the_bag_sink_puts_each_record_on_its_topic(tmp_path: Path):
    records = survey()
    assert write_survey_bag(records, tmp_path / "s.mcap") == len(records)
    with AnyReader([tmp_path / "s.mcap"]) as reader:
        topics = {name: info.msgtype for name, info in reader.topics.items()}
        strings = [
            (conn.topic, reader.deserialize(raw, conn.msgtype).data)
            for conn, _, raw in reader.messages()
            if conn.msgtype == STRING
        ]
    assert topics == {
        META_TOPIC: STRING,
        TRUTH_TOPIC: STRING,
        "/r1/odom": ODOMETRY,
        "/r1/front/detections": DETECTION3D_ARRAY,
    }
    assert [(t, json.loads(text)) for t, text in strings] == [
        (META_TOPIC, log_lines.record_to_json(records[0])),
        (TRUTH_TOPIC, log_lines.record_to_json(records[1])),
        (TRUTH_TOPIC, log_lines.record_to_json(records[2])),
    ]


def test_the_bag_sink_never_overwrites_and_checks_its_storage(tmp_path: Path):
    write_survey_bag(survey(), tmp_path / "folder", "sqlite3")
    assert (tmp_path / "folder" / "metadata.yaml").is_file()
    assert list((tmp_path / "folder").glob("*.db3"))
    with pytest.raises(FileExistsError, match="not overwriting"):
        write_survey_bag(survey(), tmp_path / "folder")
    with pytest.raises(ValueError, match=r"a \.mcap file needs storage='mcap'"):
        write_survey_bag(survey(), tmp_path / "x.mcap", "sqlite3")
