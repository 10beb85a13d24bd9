"""``solidkit.errors.library_output``: what C code writes on file descriptor 2 is captured, fd 2 comes back."""

from __future__ import annotations

import os
import threading

from solidkit.errors import library_output


def test_library_output_captures_fd_2_and_restores_it(capfd) -> None:
    with library_output() as said:
        os.write(2, b"libpng warning: iCCP: known incorrect sRGB profile\n")
        assert "iCCP" in said.text  # readable while the block runs
    os.write(2, b"after\n")
    assert said.text == "libpng warning: iCCP: known incorrect sRGB profile\n"
    assert said.summary() == "libpng warning: iCCP: known incorrect sRGB profile"
    assert capfd.readouterr().err == "after\n"


def test_nested_blocks_share_one_redirection(capfd) -> None:
    with library_output() as outer:
        os.write(2, b"one\n")
        with library_output() as inner:
            os.write(2, b"two\n")
        os.write(2, b"three\n")
    assert inner.text == "two\n" and outer.text == "one\ntwo\nthree\n"
    assert capfd.readouterr().err == ""


def test_opencv_log_lines_are_dropped_and_repeats_said_once() -> None:
    with library_output() as said:
        os.write(2, b"[ WARN:0@0.012] global loadsave.cpp:268 findDecoder imread_('x.png'): can't open\n")
        os.write(2, b"EXR_ERR_CORRUPT_CHUNK bad\nEXR_ERR_CORRUPT_CHUNK bad\n")
    assert said.lines() == ["EXR_ERR_CORRUPT_CHUNK bad", "EXR_ERR_CORRUPT_CHUNK bad"]
    assert said.summary() == "EXR_ERR_CORRUPT_CHUNK bad"


def test_concurrent_threads_restore_fd_2(capfd) -> None:
    seen: list[str] = []

    def work(k: int) -> None:
        for _ in range(20):
            with library_output() as said:
                os.write(2, f"thread {k}\n".encode())
            seen.append(said.text)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(seen) == 80 and all(text.startswith("thread ") for text in seen)
    os.write(2, b"restored\n")
    assert capfd.readouterr().err == "restored\n"
