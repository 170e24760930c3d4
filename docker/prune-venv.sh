#!/bin/sh
# Strip what a running tsdb-service never loads from a virtual environment's
# site-packages (the image's build stage runs this; see Dockerfile): the
# installers, test suites, C/C++/Cython sources and headers, Arrow Flight
# (an RPC framework pyarrow ships and nothing here imports) and its S3 file
# system (pyarrow.fs skips what it cannot import), and the link-time
# copies of libraries that are loaded by their versioned name.
set -eu
site="$1"
cd "$site"
rm -rf pip setuptools pkg_resources _distutils_hack distutils-precedence.pth pip-*.dist-info setuptools-*.dist-info
find . -depth -type d -name tests -prune -exec rm -rf {} +
find . -type f \( -name '*.pyx' -o -name '*.pxd' -o -name '*.pxi' -o -name '*.h' -o -name '*.hpp' \
    -o -name '*.cc' -o -name '*.cpp' \) -delete
rm -rf pyarrow/include pyarrow/src
rm -f pyarrow/_flight.*.so pyarrow/flight.py pyarrow/libarrow_flight.so.* pyarrow/libarrow_python_flight.so* \
    pyarrow/_pyarrow_cpp_tests.*.so pyarrow/_s3fs.*.so pyarrow/libarrow_s3.so.*
for lib in libarrow_python libarrow_python_parquet_encryption; do
    # the loader asks for lib.so.N; lib.so and lib.so.N.M.P are the same bytes again
    rm -f "pyarrow/$lib.so"
    find pyarrow -maxdepth 1 -name "$lib.so.*.*.*" -delete
done
