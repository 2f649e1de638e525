"""bag_reindex: make an unfinished or damaged bag readable by every rosbag2 reader again.

    bag_reindex bags/run1

A recording killed with SIGKILL (or stopped by a full disk) has no metadata.yaml and its MCAP
no summary or footer; rosbags and rosbag2 then refuse it. For each ``*.mcap`` of the directory
this walks the records (:mod:`rosbag_mcap.mcapfile`); a file without a valid summary, or with
damaged chunks, is finished in place: cut after its last intact record (only an incomplete
record is lost) and closed with DataEnd, a summary indexing the intact chunks, and the footer.
Then metadata.yaml is (re)written from what is readable: message counts per topic, start and
duration, the QoS offered (from the channel metadata), storage identifier mcap. Like
``ros2 bag reindex``, it needs no ROS graph.

Exit status: 0 the bag was reindexed (warnings name any damage found); 1 it cannot be
(not a directory, no .mcap file, not an MCAP file, I/O error); 2 bad command line.
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml
from mcap.reader import SeekingReader

from rosbag_mcap import mcapfile
from rosbag_mcap.metadata import (
    METADATA_FILE,
    RESERVE_FILE,
    BagError,
    dump_metadata,
    metadata_dict,
)
from rosbag_mcap.reader import topics_of


@dataclass
class FileReport:
    path: Path
    messages: int
    finished: bool  # the summary had to be written
    dropped_bytes: int  # an incomplete record cut off the end
    damaged_chunks: int
    lost_messages: int
    stop: str | None  # why the walk ended early (None: the data section was whole)


def _summary_ok(path: Path) -> bool:
    try:
        with open(path, 'rb') as stream:
            summary = SeekingReader(stream, validate_crcs=True).get_summary()
        return summary is not None and summary.statistics is not None
    except Exception:  # noqa: BLE001 (a damaged summary fails in many ways)
        return False


def _custom_data(result: mcapfile.ScanResult) -> dict | None:
    for _, _, record in result.metadata:
        if record.name == 'rosbag2':
            try:
                data = yaml.safe_load(record.metadata.get('serialized_metadata', ''))
                custom = data.get('custom_data') if isinstance(data, dict) else None
            except yaml.YAMLError:
                continue
            if isinstance(custom, dict):
                return {str(k): str(v) for k, v in custom.items()}
    return None


def repair_file(path: Path) -> tuple[mcapfile.ScanResult, FileReport]:
    """Finish ``path`` in place when it lacks a valid summary or holds damaged chunks."""
    try:
        result = mcapfile.scan(path)
    except mcapfile.McapFileError as exc:
        raise BagError(str(exc)) from None
    size = path.stat().st_size
    whole = result.data_end  # the data section was complete: only the summary is rewritten
    needs = not whole or bool(result.damaged) or not _summary_ok(path)
    report = FileReport(
        path,
        result.message_count,
        needs,
        0 if whole else size - result.intact_end,
        len(result.damaged),
        result.lost_messages,
        result.stop,
    )
    if needs:
        try:
            mcapfile.finish(result)
        except OSError as exc:
            raise BagError(f'{path}: cannot write the summary: {exc.strerror or exc}') from None
    return result, report


def write_metadata(directory: Path, results: list[mcapfile.ScanResult]) -> dict:
    """metadata.yaml of ``directory`` from the scans of its files (written atomically)."""
    files, topics, custom = [], {}, None
    for result in results:
        start = result.start_time or 0
        files.append(
            {
                'path': result.path.name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': (result.end_time or start) - start},
                'message_count': result.message_count,
            }
        )
        for name, info in topics_of(
            result.schemas, result.channels, result.channel_counts
        ).items():
            if name in topics:
                topics[name].message_count += info.message_count
            else:
                topics[name] = info
        custom = custom or _custom_data(result)
    info = metadata_dict(files=files, topics=list(topics.values()), custom_data=custom)
    tmp = directory / (METADATA_FILE + '.tmp')
    tmp.write_text(dump_metadata(info), encoding='utf-8')
    os.replace(tmp, directory / METADATA_FILE)
    return info


def reindex(directory: str | os.PathLike) -> tuple[dict, list[FileReport]]:
    """Finish the bag's MCAP files where needed and rewrite its metadata.yaml."""
    directory = Path(directory)
    if not directory.is_dir():
        raise BagError(f'{directory}: not a bag directory')
    paths = sorted(directory.glob('*.mcap'))
    if not paths:
        raise BagError(f'{directory}: no .mcap file in the directory')
    results, reports = [], []
    for path in paths:
        result, report = repair_file(path)
        results.append(result)
        reports.append(report)
    try:
        info = write_metadata(directory, results)
        (directory / RESERVE_FILE).unlink(missing_ok=True)
    except OSError as exc:
        raise BagError(
            f'{directory}: cannot write {METADATA_FILE}: {exc.strerror or exc}'
        ) from None
    return info, reports


def describe_report(report: FileReport) -> list[str]:
    """Human-readable lines about one file (the first one always, warnings after it)."""
    lines = [
        f'{report.path}: {report.messages} readable messages'
        + ('; summary and footer written' if report.finished else '; summary intact')
    ]
    if report.stop:
        lines.append(
            f'warning: {report.path}: {report.stop}; '
            f'{report.dropped_bytes} bytes after the last intact record were dropped'
        )
    if report.damaged_chunks:
        lines.append(
            f'warning: {report.path}: {report.damaged_chunks} damaged chunk(s) left out of the '
            f'index ({report.lost_messages} messages lost)'
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='bag_reindex',
        description='Rebuild metadata.yaml (and a missing MCAP summary) of a bag directory.',
    )
    parser.add_argument('bag', type=Path, help='bag directory')
    args = parser.parse_args(argv)
    try:
        info, reports = reindex(args.bag)
    except BagError as exc:
        print(f'bag_reindex: {exc}', file=sys.stderr)
        return 1
    for report in reports:
        for line in describe_report(report):
            print(f'bag_reindex: {line}', file=sys.stderr if line.startswith('warning') else None)
    topics = info['topics_with_message_count']
    print(
        f'bag_reindex: wrote {args.bag / METADATA_FILE} ({info["message_count"]} messages, '
        f'{len(topics)} topics)'
    )
    for entry in topics:
        print(f'  {entry["topic_metadata"]["name"]}: {entry["message_count"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
