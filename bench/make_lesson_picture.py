"""The README's lesson picture: a teacher's page and two students' pages of one `touch4d lesson serve`,
side by side, after the teacher's `lesson command`s changed every page's view (Debian's chromium, each
page a Quest 3 emulated by iwer, drawn inline as on a desktop). Labelled and composed with PIL.

    .venv/bin/python bench/make_lesson_picture.py [-o docs/images/lesson.png]
"""
from __future__ import annotations

import argparse
import asyncio
import io
import os
import signal
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont

from bench_lesson import serve
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from touch4d.web.lessonserver import send_command
from touch4d.web.testing import chromium, headset_page, wait_connected

WIDTH, HEIGHT = 560, 440          # each page's window
COMMANDS = [("view", "both"), ("slice", "1.2"), ("rotate", "xw 30")]
LABELS = ["teacher", "student 1", "student 2"]


@contextmanager
def lesson(out: Path):
    """`touch4d lesson serve` (no recording) until the block ends: its links; its process group stopped."""
    proc, links = serve(out, 30)
    try:
        yield links
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        proc.stdout.close()


def screenshots(out: Path) -> list[Image.Image]:
    """The three pages, once each has drawn the frame of the last command's scene revision."""
    with lesson(out) as links, chromium() as browser:
        pages = [headset_page(browser, link, WIDTH, HEIGHT) for link in (links["teacher"], links["class"], links["class"])]
        for page in pages:
            wait_connected(page)
            page.wait_for_function("touch4d.lesson && touch4d.lesson.role && touch4d.frame", timeout=30000)
        revision = pages[0].evaluate("touch4d.frame.revision")
        for verb, argument in COMMANDS:
            with ThreadPoolExecutor(1) as thread:      # (playwright's own loop runs on this thread)
                ok, text = thread.submit(asyncio.run, send_command(out, verb, argument)).result()
            if not ok:
                raise SystemExit(f"lesson command {verb} {argument}: {text}")
        shown = f"touch4d.frame.revision >= {revision + len(COMMANDS)}"
        for page in pages:
            page.wait_for_function(shown, timeout=20000)
        pages[0].wait_for_function("touch4d.lesson.roster.length === 3", timeout=20000)
        told = "touch4d.lesson.roster.every((m) => m.haptics !== '?')"
        try:
            pages[0].wait_for_function(told, timeout=5000)   # each page's haptics, as the teacher sees them
        except PlaywrightTimeout:
            print("the teacher's page still shows '?' for a page's haptics (its report did not arrive)")
        pages[0].wait_for_timeout(1500)           # each page's status line is redrawn once a second
        return [Image.open(io.BytesIO(page.screenshot())).convert("RGB") for page in pages]


def compose(shots: list[Image.Image], labels: list[str]) -> Image.Image:
    """The shots side by side, each under its label."""
    gap, band = 8, 34
    font = ImageFont.load_default(size=20)
    picture = Image.new("RGB", (sum(s.width for s in shots) + gap * (len(shots) - 1), band + max(s.height for s in shots)),
                        "white")
    draw, x = ImageDraw.Draw(picture), 0
    for shot, label in zip(shots, labels):
        draw.text((x + shot.width / 2, band / 2), label, fill="black", font=font, anchor="mm")
        picture.paste(shot, (x, band))
        x += shot.width + gap
    return picture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", default="docs/images/lesson.png")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        picture = compose(screenshots(Path(tmp) / "lesson"), LABELS)
    picture.save(args.output, optimize=True)
    print(f"{args.output}: {picture.width}x{picture.height}, {os.path.getsize(args.output) // 1024} kB")


if __name__ == "__main__":
    main()
