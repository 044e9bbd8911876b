from setuptools import find_packages, setup

package_name = "pvo_sim"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pvo maintainers",
    maintainer_email="maintainers@pvo-project.org",
    description="The synthetic world of pvo (ROS-free): procedural worlds, MuJoCo stereo rendering, sidecars",
    license="Apache-2.0",
)
