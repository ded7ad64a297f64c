"""Point the ROS 2 wheels' exported CMake targets at this machine's Python and numpy headers.

The message wheels on the package index were built in a manylinux container, and their
exported ``*__rosidl_generator_pyExport.cmake`` files name that container's include
directories (``/opt/python/cp311-cp311/...``). CMake refuses to configure a package that
links those targets while the directories do not exist. This rewrites the two paths to the
running interpreter's headers and the virtual environment's numpy headers. It is idempotent.
"""

import os
import sys
import sysconfig
from pathlib import Path

import numpy

BUILD_MACHINE_PYTHON_INCLUDE = '/opt/python/cp311-cp311/include/python3.11'
BUILD_MACHINE_NUMPY_INCLUDE = (
    '/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include')


def main() -> int:
    prefix = Path(sys.prefix)
    replacements = {
        BUILD_MACHINE_NUMPY_INCLUDE: numpy.get_include(),
        BUILD_MACHINE_PYTHON_INCLUDE: sysconfig.get_paths()['include'],
    }
    if not Path(replacements[BUILD_MACHINE_PYTHON_INCLUDE], 'Python.h').is_file():
        print(f'fix_wheel_cmake_paths: no Python.h in {replacements[BUILD_MACHINE_PYTHON_INCLUDE]}'
              ' (install the Python development headers)', file=sys.stderr)
        return 1
    rewritten = 0
    for export in sorted((prefix / 'share').glob('*/cmake/*Export*.cmake')):
        text = export.read_text()
        if '/opt/python/cp311-cp311' not in text:
            continue
        # Numpy's path contains the Python prefix, so it is replaced first.
        for old, new in replacements.items():
            text = text.replace(old, new)
        # A new file, not an edit in place: the installed file may be a hard link into an
        # installer's cache, which must keep the original.
        rewritten_export = export.with_suffix('.cmake.new')
        rewritten_export.write_text(text)
        os.replace(rewritten_export, export)
        rewritten += 1
    print(f'fix_wheel_cmake_paths: rewrote {rewritten} exported CMake file(s) under {prefix}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
