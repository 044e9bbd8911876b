from setuptools import find_packages, setup

package_name = "pvo_tools"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # `pvo` on PATH once install/setup.bash is sourced (colcon adds <prefix>/bin to PATH);
        # the same entry point is also installed to lib/pvo_tools for `ros2 run pvo_tools pvo`.
        ("bin", ["scripts/pvo"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pvo maintainers",
    maintainer_email="maintainers@pvo-project.org",
    description="The pvo command",
    license="Apache-2.0",
    entry_points={"console_scripts": ["pvo = pvo_tools.cli:main"]},
)
