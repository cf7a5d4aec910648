// The hybrid grid / kd-tree lives in accel/hybrid/ (hybrid.h: the class and its files).
#pragma once

#include "accel/hybrid/hybrid.h"
